"""Draw a pyfold run's particles in ParaView: fibres as cylinders, spheroids as
ellipsoids and spheres as spheres, each along its axis ``p``, inside the outline of
the periodic cell.

Usage (ParaView's Python, ``pvpython`` of Debian's ``paraview`` package, not the
project venv)::

    pvpython scripts/paraview_fibres.py OUT.xmf            # check: one line per frame
    xvfb-run -a -s "-screen 0 1280x1024x24" \\
        pvpython scripts/paraview_fibres.py OUT.xmf --png last.png [--time T] [--color-by NAME]

``--png`` renders the last frame (or the frame at time ``T``), coloured by the point
array ``NAME`` (default ``family``; ``none`` for one colour). Rendering needs an X
display: without one, run it under ``xvfb-run`` as above (Debian's ``xvfb``
package). In the ParaView GUI, *View → Python Shell → Run Script* on this file after
opening ``OUT.xmf`` glyphs the active source.

The recipe. ``OUT.xmf`` (``pyfold.run_results.write_xdmf``) gives one vertex cell per
particle at its centre with the axis ``p`` (three components, zero third one in
2-D), ``glyph_scale`` = (length, 2 radius, 2 radius), ``length``, ``radius``,
``shape`` (1 fibre, 2 sphere, 3 spheroid) and ``family``. The Glyph filter turns the
glyph's *x* axis onto the orientation vector after scaling the glyph by components;
hence, with orientation ``p``, scale array ``glyph_scale``, vector scale mode
"Scale by Components" and scale factor 1:

* a sphere glyph of radius 0.5 becomes the spheroid's ellipsoid (major axis
  ``length`` along ``p``, minor axes 2 radius) and a sphere's sphere (2R each way);
* a cylinder glyph of height 1 and radius 0.5 is along *y*:
  ``GlyphTransform.Rotate = (0, 0, -90)`` lays it along *x* first (without it, every
  fibre is drawn at 90 degrees to its axis).

A Threshold on ``shape`` (on the vertex cells) splits fibres from the rest. The
cell box comes from ``cell_lengths`` in the ``.xmf``'s ``Information``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import xml.etree.ElementTree as ET

#: Facets around the cylinder glyph (the test reads this to split the glyph output).
RESOLUTION = 24
#: Shape codes of ``/initial/shape``.
FIBRE, SPHERE, SPHEROID = 1, 2, 3
#: Picture size of ``--png`` [pixels].
IMAGE_SIZE = (1280, 1024)
#: The command that gives ParaView a virtual X display of that size (Debian package xvfb).
XVFB_RUN = f'xvfb-run -a -s "-screen 0 {IMAGE_SIZE[0]}x{IMAGE_SIZE[1]}x24"'


def cell_lengths(xmf: str) -> list[float] | None:
    """The periodic cell's edge lengths recorded in ``xmf`` (None when absent)."""
    for info in ET.parse(xmf).getroot().iter("Information"):
        if info.get("Name") == "cell_lengths":
            return [float(v) for v in info.get("Value", "").split()]
    return None


def _threshold(source, low: int, high: int):
    """The particles of ``source`` whose shape code lies in ``[low, high]``."""
    from paraview.simple import Threshold

    kept = Threshold(Input=source, Scalars=["POINTS", "shape"])
    kept.LowerThreshold, kept.UpperThreshold = low, high
    kept.ThresholdMethod = "Between"
    return kept


def _oriented_glyph(source, glyph_type: str):
    """A Glyph filter drawing each point's glyph along ``p``, sized by ``glyph_scale``."""
    from paraview.simple import Glyph

    glyph = Glyph(Input=source, GlyphType=glyph_type)
    glyph.OrientationArray = ["POINTS", "p"]
    glyph.ScaleArray = ["POINTS", "glyph_scale"]
    glyph.VectorScaleMode = "Scale by Components"
    glyph.ScaleFactor = 1.0
    glyph.GlyphMode = "All Points"
    return glyph


def fibre_glyphs(source, resolution: int = RESOLUTION):
    """Cylinders (unit height, diameter 1 before scaling) along ``p`` for every point of ``source``."""
    glyph = _oriented_glyph(source, "Cylinder")
    glyph.GlyphType.Resolution = resolution
    glyph.GlyphType.Height = 1.0
    glyph.GlyphType.Radius = 0.5
    glyph.GlyphTransform.Rotate = [0.0, 0.0, -90.0]
    return glyph


def ellipsoid_glyphs(source, resolution: int = RESOLUTION):
    """Ellipsoids (a sphere of diameter 1 scaled by ``glyph_scale``) along ``p`` for every point of ``source``."""
    glyph = _oriented_glyph(source, "Sphere")
    glyph.GlyphType.Radius = 0.5
    glyph.GlyphType.ThetaResolution = resolution
    # an odd number of latitude rings (poles included) puts one on the equator, so
    # that the ellipsoid reaches its full length along p (the glyph's x)
    glyph.GlyphType.PhiResolution = resolution + 1 - resolution % 2
    return glyph


def particle_glyphs(source, resolution: int = RESOLUTION) -> dict:
    """The recipe on a reader of ``OUT.xmf``: ``{"fibres": Glyph, "round": Glyph}``
    (cylinders for shape 1, ellipsoids for shapes 2 and 3)."""
    times = list(source.TimestepValues) or [0.0]
    source.UpdatePipeline(times[-1])  # array information exists only once the data is read
    missing = [name for name in ("p", "glyph_scale", "shape") if source.PointData[name] is None]
    if missing:
        raise ValueError(f"the source has no point array {', '.join(missing)}: open the .xmf that pyfold run "
                         "writes (rewrite an older one with pyfold.run_results.write_xdmf)")
    return {"fibres": fibre_glyphs(_threshold(source, FIBRE, FIBRE), resolution),
            "round": ellipsoid_glyphs(_threshold(source, SPHERE, SPHEROID), resolution)}


def frame_time(times: list[float], wanted: float | None) -> float:
    """The frame shown: the last one, or the one at time ``wanted`` (the nearest
    frame within half the smallest frame interval); ValueError naming the range otherwise."""
    if wanted is None or not times:
        return times[-1] if times else 0.0
    nearest = min(times, key=lambda t: abs(t - wanted))
    gaps = [b - a for a, b in zip(times, times[1:])]
    reach = 0.5 * min(gaps) if gaps else 0.0
    if not math.isfinite(wanted) or abs(nearest - wanted) > reach + 1e-12 * max(1.0, abs(wanted)):
        raise ValueError(f"--time: {wanted:g} is not a frame time of the file; frames at t = {times[0]:g} .. "
                         f"{times[-1]:g} ({len(times)} frames" + (f", every {min(gaps):g})" if gaps else ")"))
    return nearest


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pvpython scripts/paraview_fibres.py",
                                     description="Draw a pyfold run's particles (OUT.xmf) in ParaView.")
    parser.add_argument("xmf", nargs="?", help="OUT.xmf written by pyfold run (omit in the GUI's Python shell)")
    parser.add_argument("--png", help="write a picture of one frame to this file (needs an X display: xvfb-run)")
    parser.add_argument("--time", type=float, help="the frame's time (default: the last frame)")
    parser.add_argument("--color-by", default="family",
                        help="point array to colour by (family, shape, length, radius, p, glyph_scale; "
                             "none for one colour); default family")
    return parser


def _render(glyphs: dict, source, box: list[float] | None, t: float, color_by: str, png: str | None) -> None:
    """Show the glyphs and the cell box at time ``t``; save ``png`` when given."""
    from paraview.simple import Box, ColorBy, GetActiveViewOrCreate, GetColorTransferFunction, Outline, Render, \
        ResetCamera, SaveScreenshot, Show

    view = GetActiveViewOrCreate("RenderView")
    view.ViewSize = list(IMAGE_SIZE)
    view.ViewTime = t
    for glyph in glyphs.values():
        display = Show(glyph, view)
        if color_by.lower() == "none":
            ColorBy(display, None)
        else:
            ColorBy(display, ("POINTS", color_by))
            display.SetScalarBarVisibility(view, True)
    if color_by.lower() != "none":  # one colour scale over every particle (not the last glyph set's range)
        source.UpdatePipeline(t)
        array = source.PointData[color_by]
        low, high = array.GetRange(-1 if array.GetNumberOfComponents() > 1 else 0)
        GetColorTransferFunction(color_by).RescaleTransferFunction(low, high if high > low else low + 1.0)
    if box is not None:
        lengths = (list(box) + [0.0, 0.0])[:3]
        cell = Box(XLength=lengths[0], YLength=lengths[1], ZLength=lengths[2],
                   Center=[0.5 * v for v in lengths])
        outline = Show(Outline(Input=cell), view)
        outline.AmbientColor = outline.DiffuseColor = [0.2, 0.2, 0.2]
    if box is not None and len(box) == 2:
        view.InteractionMode = "2D"
    ResetCamera(view)
    Render(view)
    if png:
        SaveScreenshot(png, view, ImageResolution=list(IMAGE_SIZE))


def main(argv: list[str]) -> int:
    """Command line: exit 0 when drawn, 2 on a bad argument or file, 1 when ``--png`` has no
    X display to render on (a message, no traceback)."""
    args = _parser().parse_args(argv)
    if args.png and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        # ParaView's X build would crash (SIGSEGV) on the first render: say what to do instead
        print(f"paraview_fibres: --png needs an X display and DISPLAY is not set; run it under Xvfb: {XVFB_RUN} "
              "pvpython scripts/paraview_fibres.py ...", file=sys.stderr)
        return 1
    from paraview.simple import GetActiveSource, OpenDataFile

    if args.xmf is None:
        source, box = GetActiveSource(), None
        if source is None:
            print("paraview_fibres: no file given and no active source; usage: pvpython paraview_fibres.py OUT.xmf",
                  file=sys.stderr)
            return 2
    else:
        # an absolute name: ParaView's default reader joins a bare file name to the HDF5 name wrongly
        xmf = os.path.abspath(args.xmf)
        if not os.path.isfile(xmf):
            print(f"paraview_fibres: {args.xmf}: no such file (give the OUT.xmf that pyfold run writes)",
                  file=sys.stderr)
            return 2
        try:
            box = cell_lengths(xmf)
        except ET.ParseError as exc:
            print(f"paraview_fibres: {args.xmf} is not an XDMF file: {exc}", file=sys.stderr)
            return 2
        source = OpenDataFile(xmf)
        if source is None:
            print(f"paraview_fibres: ParaView cannot open {args.xmf}", file=sys.stderr)
            return 2
    times = list(source.TimestepValues) or [0.0]
    try:
        t = frame_time(times, args.time)
        glyphs = particle_glyphs(source)
    except ValueError as exc:
        print(f"paraview_fibres: {exc}", file=sys.stderr)
        return 2
    names = sorted(source.PointData.keys())
    if args.color_by.lower() != "none" and args.color_by not in names:
        print(f"paraview_fibres: --color-by: no point array {args.color_by!r}; choose one of {', '.join(names)} "
              "or none", file=sys.stderr)
        return 2
    for k, frame in enumerate(times):
        counts = []
        for kind, glyph in glyphs.items():
            glyph.UpdatePipeline(frame)
            counts.append(f"{glyph.GetDataInformation().GetNumberOfPoints()} {kind} glyph points")
        source.UpdatePipeline(frame)
        info = source.GetDataInformation()
        print(f"frame {k}: t = {frame:g}: {info.GetNumberOfPoints()} particles in {info.GetNumberOfCells()} "
              f"vertex cells; " + ", ".join(counts))
    if args.png or args.xmf is None:
        _render(glyphs, source, box, t, args.color_by, args.png)
        if args.png:
            print(f"paraview_fibres: frame t = {t:g} drawn to {args.png}")
    return 0


if __name__ == "__main__":
    status = main(sys.argv[1:])
    if status:  # on success the script just ends: sys.exit after a render makes pvpython's
        sys.exit(status)  # teardown fail (GLXBadContext under Xvfb) and exit 1
