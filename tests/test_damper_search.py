"""Where several dampers go (``optimise`` with ``CoordinateDescent``): the search against the
enumeration of every placement (each with its coefficients optimised) on small chains, and the
refusals."""

import itertools

import numpy as np
import pytest

import mikota_jax as mj

N, LOWEST = 12, 5
EVERY_DOF = list(range(1, N + 1))


def coefficients(system):
    """The optimised trace of ``system``'s dampers where they are (``Coefficients``)."""
    return mj.optimise(mj.DamperDesign(system, mj.AverageEnergy(LOWEST)), mj.Coefficients())


def place(system, objective=None, *, positions=None, pairs=None, **strategy):
    """``optimise`` with ``CoordinateDescent`` (the trace of the ``LOWEST`` modes)."""
    objective = mj.AverageEnergy(LOWEST) if objective is None else objective
    design = mj.DamperDesign(system, objective, positions=positions, pairs=pairs)
    return mj.optimise(design, mj.CoordinateDescent(**strategy))


def chain(positions, relative=None):
    dampers = [mj.GroundedDamper(p, 1.0) for p in positions]
    if relative is not None:
        dampers.append(mj.RelativeDamper(relative, 1.0))
    return mj.mikota_chain(N, dampers=dampers, internal_damping=mj.ModalDamping(0.02))


def enumeration(count, candidates, relative=None):
    """min over every placement of ``count`` dampers on ``candidates`` of the optimised trace."""
    best = None
    for positions in itertools.combinations(candidates, count):
        result = coefficients(chain(positions, relative))
        if best is None or result.value < best[0]:
            best = (result.value, positions)
    return best


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_two_dampers_and_a_relative_one_reach_the_enumerations_optimum():
    # start at DOFs 2 and 3, where the search at one coefficient alone stalls (at 10 and 1)
    candidates = list(range(1, N + 1))
    value, positions = enumeration(2, candidates, relative=(5, 9))
    found = place(chain([2, 3], relative=(5, 9)), positions=EVERY_DOF)
    assert found.stats["status"].startswith("converged"), found.stats["status"]
    assert found.value <= value * (1 + 1e-9)
    assert sorted(found.positions) == sorted(positions)
    assert found.coefficients.shape == (3,) and np.all(found.coefficients > 0)
    # the trace at the returned design is the value reported (an independent evaluation)
    dampers = [mj.GroundedDamper(p, c) for p, c in zip(found.positions, found.coefficients[:2])]
    check = mj.mikota_chain(N, dampers=[*dampers, mj.RelativeDamper((5, 9),
                                                                      found.coefficients[2])],
                            internal_damping=mj.ModalDamping(0.02))
    assert float(mj.AverageEnergy(LOWEST)(check)) == pytest.approx(found.value, rel=1e-12)
    # fewer polishes than the enumeration's C(12, 2) = 66
    assert found.stats["polishes"] < 66


@pytest.mark.slow
def test_three_dampers_on_candidates_reach_the_enumerations_optimum():
    candidates = [1, 3, 4, 6, 8, 10, 12]
    value, positions = enumeration(3, candidates)
    found = place(chain([1, 3, 4]), positions=candidates)
    assert found.value <= value * (1 + 1e-9)
    assert sorted(found.positions) == sorted(positions)


@pytest.mark.slow  # ~60 s: 25 optimisations for the enumeration, six descents
def test_a_grounded_and_a_relative_damper_moved_together_reach_the_enumerations_optimum():
    # the relative damper's pair is chosen from candidate pairs, the grounded damper's DOF from
    # candidate DOFs: every one of the 5 x 5 placements, each with both coefficients optimised
    candidates = [1, 3, 6, 9, 12]
    pairs = [(2, 3), (1, 4), (5, 9), (6, 12), (1, 12)]
    enumerated = min(
        (coefficients(chain([p], relative=pair)).value, p, pair)
        for p in candidates for pair in pairs)
    # from DOF 9 and pair (2, 3) the search stops at a coordinate-wise minimum (DOF 12, pair
    # (1, 4): 15.54 against 14.28), and so do most random starts (measured with seed 0: four of
    # the first five; (6, (5, 9)) at 15.63 is a third basin); the sixth lands in the optimum's
    found = place(chain([9], relative=(2, 3)), positions=candidates, pairs=pairs, starts=6,
                  seed=0)
    assert found.stats["start_values"][0] > enumerated[0] * 1.05
    assert found.stats["status"].startswith("converged"), found.stats["status"]
    assert found.value <= enumerated[0] * (1 + 1e-9)
    assert found.positions.tolist() == [enumerated[1]]
    assert sorted(found.pairs[0].tolist()) == sorted(enumerated[2])
    # the reported value is the trace of the returned design, built anew
    check = mj.mikota_chain(N, dampers=[
        mj.GroundedDamper(found.positions[0], found.coefficients[0]),
        mj.RelativeDamper(tuple(found.pairs[0].tolist()), found.coefficients[1])],
        internal_damping=mj.ModalDamping(0.02))
    assert float(mj.AverageEnergy(LOWEST)(check)) == pytest.approx(found.value, rel=1e-12)


@pytest.mark.slow
def test_a_relative_damper_alone_moves_among_candidate_pairs():
    # it starts at (2, 3), no candidate: on the nearest one, (1, 4)
    pairs = [(1, 4), (5, 9), (6, 12), (1, 12)]
    system = mj.mikota_chain(N, dampers=[mj.RelativeDamper((2, 3), 1.0)],
                             internal_damping=mj.ModalDamping(0.02))
    best = min((coefficients(mj.mikota_chain(
        N, dampers=[mj.RelativeDamper(pair, 1.0)], internal_damping=mj.ModalDamping(0.02)))
        .value, pair) for pair in pairs)
    found = place(system, pairs=pairs)
    assert found.value == pytest.approx(best[0], rel=1e-9)
    assert sorted(found.pairs[0].tolist()) == sorted(best[1])
    assert found.positions.shape == (0,)


@pytest.mark.parametrize("kwargs, match", [
    (dict(positions=[0, 3]), "positions must be"),
    (dict(positions=[2.5]), "positions must be"),
    (dict(positions=[3, 3]), "positions must be"),
    (dict(keep=0), "keep must be"),
    (dict(max_sweeps=1.5), "max_sweeps must be"),
    (dict(starts=0), "starts must be"),
    (dict(objective="maximum"), "objective must be an AbstractObjective"),
    (dict(positions=[3]), r"^mikota_jax: positions must hold at least one DOF per grounded "
     r"damper \(2\), got 1\.$"),
])
def test_bad_arguments_are_named(kwargs, match):
    kwargs = dict(positions=EVERY_DOF) | kwargs
    with pytest.raises(ValueError, match=match):
        place(chain([2, 3]), **kwargs)


@pytest.mark.parametrize("pairs", [[(1, 1)], [(1, 13)], [(1, 2), (2, 1)], [1, 2], [(1.5, 3)],
                                   [(1, 2, 3)], []])
def test_bad_pair_candidates_are_named(pairs):
    with pytest.raises(ValueError, match="pairs must be"):
        place(chain([2], relative=(5, 9)), pairs=pairs)


def test_fewer_candidate_pairs_than_relative_dampers_is_refused_in_one_line():
    system = mj.mikota_chain(N, dampers=[mj.RelativeDamper((2, 5), 1.0),
                                         mj.RelativeDamper((6, 9), 1.0)])
    with pytest.raises(ValueError, match=r"^mikota_jax: pairs must hold at least one "
                       r"pair per relative damper \(2\), got 1\.$"):
        place(system, pairs=[(1, 3)])


@pytest.mark.slow
def test_dampers_off_the_candidates_start_on_the_nearest_free_ones_and_end_on_candidates():
    # dampers at DOFs 2 and 5, candidates 3 and 4: the only placement is (3, 4); before, the
    # DOF-5 damper could not move (3 taken by the other) and came back at 5, no candidate
    only = place(chain([2, 5]), positions=[3, 4])
    assert sorted(only.positions.tolist()) == [3.0, 4.0]
    assert only.value == pytest.approx(
        coefficients(chain([3, 4])).value, rel=1e-12)


@pytest.mark.slow  # default-run time: the screening compiles for this structure (~30 s)
def test_dampers_off_three_candidates_end_on_them_at_the_enumerations_optimum():
    candidates = [1, 3, 6]
    value, positions = enumeration(2, candidates)
    found = place(chain([2, 5]), positions=candidates)
    assert set(found.positions.tolist()) <= set(candidates)
    assert sorted(found.positions.tolist()) == sorted(positions)
    assert found.value <= value * (1 + 1e-9)


def test_a_system_without_dampers_to_move_is_refused():
    system = mj.mikota_chain(N, dampers=[mj.RelativeDamper((2, 5), 1.0)])
    with pytest.raises(ValueError, match="nothing to place"):
        place(system)
    with pytest.raises(ValueError, match="no RelativeDamper to move"):
        place(chain([2]), pairs=[(1, 3)])
    # Coefficients keeps the dampers where they are: candidates are CoordinateDescent's
    with pytest.raises(ValueError, match="positions/pairs must be None for Coefficients"):
        mj.optimise(mj.DamperDesign(chain([2]), mj.AverageEnergy(LOWEST), positions=[1, 2]),
                    mj.Coefficients())
