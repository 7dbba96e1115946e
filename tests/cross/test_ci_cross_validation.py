"""Cross-validation of the C_I estimators on an ensemble of concentrated contacts-only runs.

Four seeds of one scene (pyfold.scene.sheared_fibres: beta = 10, n L^3 = 15, 207 fibres,
alpha = 0.2 d, Jeffery kinematics + the collision strategy, simple shear from isotropy to
two Jeffery periods, strain 104). What a contacts-only suspension gives
(docs/physics.md#what-contacts-alone-do, studies/interaction_coefficient/ci_concentration.py):

* the C_I a moulding code running IBOF should use, the trajectory fit of Folgar-Tucker
  with IBOF to a2(t) (pyfold.fast_fit.fit_ci_rk4), is positive beyond 3 standard
  errors (across the seeds, and of each seed's fit) and inside the published range (1e-4 ... 3e-2,
  pyfold.correlations.PUBLISHED_RANGE);
* the rate regression with the runs' own a4 (closure-free) is not a positive diffusion
  (contacts align the fibres further instead of spreading them); with the closure's a4
  evaluated on the same a2 it is larger, paired over the seeds: the closure's a4:D error
  is absorbed into C_I. These are the reasons the estimators differ; a change of the
  contact model or of the estimators that removed them would fail here and must update
  the study and docs/physics.md.

The dilute identity (no contacts: C_I = 0 with the run's own a4) is
tests/cross/test_ci_methods.py and tests/cross/test_chain_dilute.py.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pyfold import run_checks
from pyfold.commands import run as run_command
from pyfold.ci_estimators import ci_rate_regression
from pyfold.correlations import PUBLISHED_RANGE
from pyfold.ensemble import ensemble_mean, paired_difference
from pyfold.run_analysis import closure_a4
from pyfold.run_results import open_run
from pyfold.scene.sheared_fibres import sheared_fibres

SEEDS = (21, 22, 23, 24)
BETA, N_L3, ALPHA_OVER_D = 10.0, 15.0, 0.2
#: two Jeffery periods at the run's beta_e (Cox: 8.17 for beta 10): 2 * 2 pi (8.17 + 1/8.17) = 104
T_END = 104.0


@pytest.fixture(scope="module")
def ensemble(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ci_cross")
    out = []
    for seed in SEEDS:
        scene = sheared_fibres(BETA, N_L3, seed, T_END, alpha_over_d=ALPHA_OVER_D)
        path = folder / f"s{seed}.toml"
        path.write_text(scene.toml, encoding="utf-8")
        run = run_command.run_scene(path, folder / f"s{seed}.h5")
        ds = open_run(run)
        out.append(dict(t=ds["time"].values, a2=ds["a2"].values, a4=ds["a4"].values,
                        L=run_checks.velocity_gradient_of(run)[:3, :3], xi=run_checks.shape_factor_of(ds)))
        ds.close()
    return out


def test_concentrated_contacts_give_a_positive_effective_c_i_in_the_published_range(ensemble):
    from pyfold.fast_fit import fit_ci_rk4

    fits = [fit_ci_rk4("ibof", r["t"], r["a2"], r["L"], r["xi"], t_end=T_END) for r in ensemble]
    assert all(f.success for f in fits), [f.message for f in fits]
    m = ensemble_mean([f.ci for f in fits], [f.stderr for f in fits])
    assert m.mean > 3.0 * m.error, (fits, m)
    assert PUBLISHED_RANGE[0] <= m.mean <= PUBLISHED_RANGE[1], (fits, m)


def test_closure_free_c_i_is_no_diffusion_and_the_closure_error_raises_it(ensemble):
    own, with_ibof = [], []
    for r in ensemble:
        window = (T_END / 2, T_END)  # the second Jeffery period: past the fast alignment from isotropy
        own.append(ci_rate_regression(r["t"], r["a2"], r["a4"], r["L"], r["xi"], window=window).ci)
        a4_ibof = closure_a4("ibof", r["a2"])
        with_ibof.append(ci_rate_regression(r["t"], r["a2"], a4_ibof, r["L"], r["xi"], window=window).ci)
    m_own = ensemble_mean(own)
    assert m_own.mean < 3.0 * m_own.stderr_across, own  # not a positive diffusion
    diff = paired_difference(with_ibof, own)
    assert diff.mean > 3.0 * diff.stderr, (own, with_ibof, diff)
    assert math.isfinite(diff.stderr) and diff.n == len(SEEDS)
