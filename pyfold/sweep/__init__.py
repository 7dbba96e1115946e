"""Sweeps: many runs of one kind of scene, described once, run anywhere, gathered into one dataset.

A sweep file (TOML, :mod:`pyfold.sweep.spec`) names a base scene (a scene file, or a
Python builder such as :func:`pyfold.scene.sheared_fibres.sheared_fibres`), axes over
scene keys or builder arguments, seeds, and per-run resources. :mod:`pyfold.sweep.plan`
expands it into runs, each identified by a content hash of its normalised scene
(:func:`pyfold.sweep.plan.run_id`), so a run is never computed twice. The sweep folder
(:mod:`pyfold.sweep.store`) keeps one folder per run (``runs/<id>/``: scene, run file,
attempts); an executor (:mod:`pyfold.sweep.executors`: ``local`` or ``slurm``) runs
what is missing, each run through :mod:`pyfold.sweep.worker` (``pyfold run``, resumed
from its checkpoint when it was interrupted, or started as a copy of a finished run of its
scene to an earlier end, :mod:`pyfold.sweep.donors`); :mod:`pyfold.sweep.gather` builds
``sweep.nc`` over the sweep's axes and seed.

Command line: ``pyfold sweep run|status|gather`` (:mod:`pyfold.commands.sweep`);
docs/cluster.md explains the sweep file and running on a Slurm cluster.
"""
