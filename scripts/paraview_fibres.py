"""Draw a pyfold run's particles in ParaView as cylinders along their axes.

Usage (ParaView's Python, not the project venv)::

    pvpython scripts/paraview_fibres.py OUT.xmf                   # check: prints one line per frame
    xvfb-run pvpython scripts/paraview_fibres.py OUT.xmf --png fibres.png   # a picture of the last frame

or, in the ParaView GUI, *View → Python Shell → Run Script* on this file after
opening ``OUT.xmf`` (it then glyphs the active source).

The recipe. ``OUT.xmf`` (``pyfold.runs.write_xdmf``) gives points at the particle
centres with the axis ``p`` (2 or 3 components), ``length`` and ``radius``.
ParaView's cylinder glyph has its axis along y, height 1 and radius 0.5, and the
Glyph filter turns the glyph's *x* axis onto the orientation vector; hence

1. ``GlyphTransform.Rotate = (0, 0, -90)`` lays the cylinder along x (without it,
   every fibre is drawn at 90 degrees to its axis);
2. scaling by components with ``(length, 2 radius, 2 radius)`` gives each particle
   its own length and diameter (the transform is applied before the scaling, the
   orientation after it);
3. the orientation array is ``p`` padded to three components (2-D runs store two).

Spheres (shape 2) come out as short cylinders of length 2R; spheroids as cylinders
of their major axis and diameter.
"""
from __future__ import annotations

import sys

#: Facets around the cylinder glyph (the test reads this to split the glyph output).
RESOLUTION = 24


def fibre_glyphs(source, resolution: int = RESOLUTION):
    """The pipeline of the recipe on a reader of ``OUT.xmf``; returns the Glyph filter."""
    from paraview.simple import Calculator, Glyph

    times = list(source.TimestepValues) or [0.0]
    source.UpdatePipeline(times[0])  # array information exists only once the data is read
    info = source.PointData["p"]
    if info is None:
        raise RuntimeError("the source has no point array 'p': open the .xmf that pyfold run writes")
    ncomp = info.GetNumberOfComponents()
    axis = Calculator(Input=source, ResultArrayName="axis",
                      Function="p_X*iHat + p_Y*jHat" + (" + p_Z*kHat" if ncomp == 3 else ""))
    size = Calculator(Input=axis, ResultArrayName="glyph_scale",
                      Function="length*iHat + 2*radius*jHat + 2*radius*kHat")
    glyph = Glyph(Input=size, GlyphType="Cylinder")
    glyph.GlyphType.Resolution = resolution
    glyph.GlyphType.Height = 1.0
    glyph.GlyphType.Radius = 0.5
    glyph.GlyphTransform.Rotate = [0.0, 0.0, -90.0]
    glyph.OrientationArray = ["POINTS", "axis"]
    glyph.ScaleArray = ["POINTS", "glyph_scale"]
    glyph.VectorScaleMode = "Scale by Components"
    glyph.ScaleFactor = 1.0
    glyph.GlyphMode = "All Points"
    return glyph


def main(argv: list[str]) -> int:
    from paraview.simple import GetActiveSource, OpenDataFile, SaveScreenshot, Show, Render, ResetCamera

    if not argv:
        source = GetActiveSource()
        if source is None:
            print("usage: pvpython paraview_fibres.py OUT.xmf [--png FILE]", file=sys.stderr)
            return 2
    else:
        source = OpenDataFile(argv[0])
        if source is None:
            print(f"paraview_fibres: cannot open {argv[0]}", file=sys.stderr)
            return 2
    glyph = fibre_glyphs(source)
    times = list(source.TimestepValues) or [0.0]
    for t in times:
        glyph.UpdatePipeline(t)
        print(f"t = {t:g}: {glyph.GetDataInformation().GetNumberOfPoints()} glyph points")
    if "--png" in argv:
        Show(glyph)
        ResetCamera()
        Render()
        SaveScreenshot(argv[argv.index("--png") + 1])
    elif not argv:
        Show(glyph)
        Render()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
