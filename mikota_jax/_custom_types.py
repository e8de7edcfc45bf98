"""Array type aliases used in public signatures (jaxtyping)."""

from jaxtyping import Array, ArrayLike, Complex, Float, Int

Vector = Float[Array, " n"]
Matrix = Float[Array, "n n"]
Basis = Float[Array, "n r"]
Snapshots = Float[Array, "n m"]
Times = Float[Array, " N"]
ScalarLike = float | Float[ArrayLike, ""]

__all__ = ["Array", "ArrayLike", "Basis", "Complex", "Float", "Int", "Matrix", "ScalarLike",
           "Snapshots", "Times", "Vector"]
