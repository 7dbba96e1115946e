"""Fibre orientation models for the second-order tensor ``a2`` and their integration.

Every model is an :class:`equinox.Module` whose float fields are its parameters
(dynamic float64 leaves: ``dataclasses.replace(model, ci=0.02)``, ``eqx.tree_at``
and gradients work) with a ``closure`` (name, ``f(a2)`` or ``TabulatedA4``) and a
static ``dim`` (3, or 2 for planar orientation). ``model.rate(t, a2, L)`` is the
pure right-hand side ``Da2/Dt``; :func:`solve_orientation` and :func:`solve_batch`
integrate it with diffrax.
"""
from __future__ import annotations

from pyfold.models._base import OrientationModel
from pyfold.models.ard import ARDRSC, IARD, IARDRPR, PARD, PARDRPR
from pyfold.models.folgar_tucker import FTMS, FolgarTucker
from pyfold.models.jeffery import Jeffery, jeffery_vectors
from pyfold.models.mori_tanaka import MoriTanaka
from pyfold.models.mrd import MRD
from pyfold.models.rsc import RSC
from pyfold.models.solve import OrientationSolution, solve_batch, solve_orientation, status_message

__all__ = [
    "OrientationModel",
    "Jeffery",
    "FolgarTucker",
    "FTMS",
    "RSC",
    "ARDRSC",
    "IARD",
    "IARDRPR",
    "PARD",
    "PARDRPR",
    "MRD",
    "MoriTanaka",
    "jeffery_vectors",
    "OrientationSolution",
    "solve_orientation",
    "solve_batch",
    "status_message",
    "MODELS",
]

#: name -> model class, for command-line tools and studies.
MODELS: dict[str, type[OrientationModel]] = {
    "jeffery": Jeffery,
    "folgar_tucker": FolgarTucker,
    "ftms": FTMS,
    "rsc": RSC,
    "ard_rsc": ARDRSC,
    "iard": IARD,
    "iard_rpr": IARDRPR,
    "pard": PARD,
    "pard_rpr": PARDRPR,
    "mrd": MRD,
    "mori_tanaka": MoriTanaka,
}
