"""Sub-commands of the ``pyfold`` CLI (see :mod:`pyfold.cli`)."""
