"""The optimizer's CasADi model of a rig with a GNSS antenna is the evaluator's information.

A GNSS antenna breaks the gauge (world position and yaw are observed): every consumer closes its
drives through :mod:`excite.information.closure` (world states with the drive's origin, no gauge,
the first fix opening the error's chain), and each must agree with the evaluator."""

from __future__ import annotations

import numpy as np
import pytest
from excite.information.closure import marginalise_nuisance
from excite.information.problem import columns
from excite.motion.maneuvers import figure_eight
from excite.motion.vehicle import drive
from helpers import gnss_rig
from helpers import model_samples


@pytest.fixture(scope="module")
def rig():
    return gnss_rig(lidar=True)


@pytest.fixture(scope="module")
def traj(rig):
    return drive(figure_eight(40.0), rig.suspension)


def test_the_optimizers_model_is_the_evaluators_information(rig, traj):
    from excite.factors.base import Nominal
    from excite.information import elimination, problem
    from excite.plan.model import build_model, coarse_rig

    coarse = coarse_rig(rig, 2.0, 4)
    nom = Nominal.of(traj, coarse)
    _, args = model_samples(traj, coarse)
    model = build_model(coarse, nom.n_keyframes)
    got = np.array(model.marginal(*args))  # plain world states, over the rig's coordinates
    ref = elimination.marginal(problem.build(nom, coarse))  # the drive's origin among the nuisances
    P = len(coarse.coordinates)
    nuisance = np.array([c.nuisance for c in coarse.coordinates])
    a = marginalise_nuisance(got, ~nuisance)
    r = marginalise_nuisance(ref, ~columns(coarse, 1)[1])
    assert np.abs(a - r).max() <= 1e-6 * np.abs(r).max()
    assert got.shape == (P, P)
    i = [c.name for c in coarse.scored].index("gnss.time_offset")
    assert r[i, i] > 0
