"""Influence of the security zone α on the fitted interaction coefficient C_I.

Question
    The seed's collision strategy keeps every pair of particles at least α apart
    (a security zone that "depends on the mesh"). Does the choice of α change
    the orientation statistics a direct simulation produces, and so the C_I a
    moulding code would be given? (Open question of the seed's conclusions.)

Command
    .venv/bin/python studies/alpha_influence/alpha_influence.py [--alphas 0.0025 0.005 0.01 0.02]
    Cost: one run of the bundled default scene (128 fibres, β = 10, 2000 steps) and
    two Folgar–Tucker fits per α: about 30 s per α on 2 cores.

Outputs (under out/studies/alpha_influence/)
    alpha_influence.nc   C_I (exact and IBOF closures), contact statistics per α
    alpha_influence.png  C_I and contact corrections versus α
    a printed table
"""
from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold import pipeline
from pyfold.commands.main_job import DEFAULT_SCENE
from pyfold.runs import open_run

# Parameters
CLOSURES = ("exact", "ibof")


#: This study's span and record spacing: the transient of the default scene (strain 20,
#: 201 records); the default scene itself runs longer, for the main job's ensemble.
T_END, INTERVAL = 20.0, 0.1


def _replace(text: str, key: str, value: float) -> str:
    new, count = re.subn(rf"(?m)^{key}\s*=\s*[0-9.eE+-]+", f"{key} = {value!r}", text)
    if count != 1:
        raise SystemExit(f"the default scene has no single '{key} = ...' line to vary")
    return new


def scene_with_alpha(text: str, alpha: float) -> str:
    """The default scene with ``model.alpha`` replaced (the only physical change), run over this
    study's span ``T_END`` with records every ``INTERVAL``."""
    return _replace(_replace(_replace(text, "alpha", alpha), "t_end", T_END), "interval", INTERVAL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--alphas", type=float, nargs="+", default=[0.0025, 0.005, 0.01, 0.02])
    parser.add_argument("--out", type=Path, default=Path("out/studies/alpha_influence"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    # Problem: the bundled default scene, α varied
    base = DEFAULT_SCENE.read_text()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for alpha in args.alphas:
            scene = Path(tmp) / f"alpha_{alpha:g}.toml"
            scene.write_text(scene_with_alpha(base, alpha))
            # Solver: direct simulation, then the fits
            run_path = pipeline.run_scene(scene, Path(tmp) / f"alpha_{alpha:g}.h5")
            ds = open_run(run_path)
            fits = pipeline.fit_ci_per_closure(ds, pipeline.velocity_gradient_of(run_path), CLOSURES,
                                               pipeline.shape_factor_of(ds))
            rows.append(dict(
                alpha=alpha,
                ci=fits["ci"].values, ci_stderr=fits["ci_stderr"].values,
                residual=fits["residual_rms"].values,
                corrections=float(ds["n_corrections"].sum()),
                max_iterations=int(ds["contact_iterations"].max()),
                min_gap_over_alpha=float(ds["min_gap_over_alpha"].min()),
                a11_end=float(ds["a2"].values[-1, 0, 0]),
            ))

    # Save
    result = xr.Dataset(
        {
            "ci": (("alpha", "closure"), np.array([r["ci"] for r in rows]), {"units": "1"}),
            "ci_stderr": (("alpha", "closure"), np.array([r["ci_stderr"] for r in rows]), {"units": "1"}),
            "residual_rms": (("alpha", "closure"), np.array([r["residual"] for r in rows]), {"units": "1"}),
            "contact_corrections": ("alpha", [r["corrections"] for r in rows], {"units": "1"}),
            "max_contact_iterations": ("alpha", [r["max_iterations"] for r in rows], {"units": "1"}),
            "min_gap_over_alpha": ("alpha", [r["min_gap_over_alpha"] for r in rows], {"units": "1"}),
            "a11_final": ("alpha", [r["a11_end"] for r in rows], {"units": "1"}),
        },
        coords={"alpha": ("alpha", args.alphas, {"units": "m", "long_name": "security zone"}),
                "closure": list(CLOSURES)},
        attrs={"scene": str(DEFAULT_SCENE), "question": "influence of the security zone alpha on C_I"},
    )
    result.to_netcdf(args.out / "alpha_influence.nc", engine="h5netcdf")
    _figure(result, args.out / "alpha_influence.png")
    print(f"{'alpha':>8} {'C_I exact':>11} {'C_I ibof':>11} {'corrections':>12} {'a11(t_end)':>10}")
    for r in rows:
        print(f"{r['alpha']:8.4f} {r['ci'][0]:11.3e} {r['ci'][1]:11.3e} {r['corrections']:12.0f} {r['a11_end']:10.4f}")
    print(f"written: {args.out}")


def _figure(result: xr.Dataset, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 3.4), layout="constrained")
    left, right = fig.subplots(1, 2)
    for closure in result["closure"].values:
        left.errorbar(result["alpha"], result["ci"].sel(closure=closure),
                      yerr=result["ci_stderr"].sel(closure=closure), marker="o", capsize=3, label=closure)
    left.set_xscale("log")
    left.set_xlabel("security zone α [m]")
    left.set_ylabel("fitted C_I")
    left.legend(frameon=False)
    left.grid(alpha=0.3)
    right.semilogx(result["alpha"], result["contact_corrections"], "o-")
    right.set_xlabel("security zone α [m]")
    right.set_ylabel("contact corrections over the run")
    right.grid(alpha=0.3)
    fig.savefig(path, dpi=130)


if __name__ == "__main__":
    main()
