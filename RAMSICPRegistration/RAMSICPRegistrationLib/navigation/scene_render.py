"""An offscreen picture of a registration (VTK), readable without a caption: the bone surface (IPC), the probe
points coloured by their residual, the reference body's marker spheres, the targets and the planned cut, with a
legend, a residual colour bar, a scale bar and the patient's orientation (R, A, S axes).

The view is orthographic, so the scale bar holds everywhere in the picture. Without a display (``DISPLAY`` unset)
VTK is told to render through EGL before its first window, which avoids its "bad X server connection" warning.
"""

import os

import numpy as np

from ..io.atomic_files import atomic_path
from ..io.file_checks import check_output_file
from ..io.ndi_tools import MARKER_DIAMETER_MM
from ..io.vtk_arrays import poly_data

#: Residuals from 0 (green) to this (red), mm.
RESIDUAL_SCALE_MM = 1.0

BONE_COLOUR = (0.89, 0.85, 0.75)
MARKER_COLOUR = (0.55, 0.62, 0.78)
TARGET_COLOUR = (0.93, 0.25, 0.86)
CUT_COLOUR = (0.30, 0.75, 0.95)


def use_offscreen_rendering():
    """Render through EGL when there is no X display (set before VTK creates its first render window)."""
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def check_writable_png(path):
    """Raise ValueError naming the problem when ``path`` cannot receive a PNG (checked before any work)."""
    check_output_file(path, "screenshot", (".png",))


def render_registration(
    path,
    ipc_points,
    ipc_triangles,
    probe_points,
    residuals_mm,
    marker_centres,
    targets=None,
    cut=None,
    size=(1000, 760),
    title="CR-RAMSICP registration",
    view_direction=(-260.0, 320.0, 90.0),
):
    """Render a registration to a PNG file; every coordinate is image RAS (mm).

    Args:
        ipc_points, ipc_triangles: the bone surface (M, 3) and its triangles (K, 3) or None (points only).
        probe_points: (N, 3) registered probe points; ``residuals_mm`` (N,) their distances to the IPC.
        marker_centres: (4, 3) reference-body sphere centres, drawn as 11.5 mm spheres.
        targets: optional (T, 3) target points (the ends of the planned cut).
        cut: optional (point (3,), normal (3,)) of the planned osteotomy plane, drawn across the bone.
        view_direction: from the scene's centre towards the camera (RAS); the default looks from antero-medial.

    Raises:
        ValueError: the PNG cannot be written (checked before rendering); OSError: writing it failed.
    """
    check_writable_png(path)
    use_offscreen_rendering()
    import vtkmodules.vtkRenderingFreeType  # noqa: F401  (text)
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL back end)
    from vtkmodules.vtkRenderingCore import vtkRenderer

    renderer = vtkRenderer()
    renderer.SetBackground(0.12, 0.13, 0.16)
    legend = []  # (label, colour, symbol)
    renderer.AddActor(_surface_actor(ipc_points, ipc_triangles))
    legend.append(("bone surface (IPC)", BONE_COLOUR, "square"))
    lookup = _residual_lookup()
    renderer.AddActor(_glyph_actor(probe_points, 1.5, scalars=residuals_mm, lookup=lookup))
    legend.append(("probe points, coloured by residual", (0.4, 0.85, 0.3), "sphere"))
    renderer.AddActor(_glyph_actor(marker_centres, MARKER_DIAMETER_MM / 2.0, colour=MARKER_COLOUR))
    legend.append(("reference body's marker spheres (11.5 mm)", MARKER_COLOUR, "sphere"))
    framed = [probe_points, marker_centres]
    if cut is not None:
        renderer.AddActor(_cut_actor(cut, ipc_points))
        legend.append(("planned osteotomy cut", CUT_COLOUR, "square"))
    if targets is not None and len(targets):
        renderer.AddActor(_glyph_actor(targets, 3.0, colour=TARGET_COLOUR, cube=True))
        legend.append(("targets: the ends of the cut", TARGET_COLOUR, "cube"))
        framed.append(targets)

    camera = renderer.GetActiveCamera()
    _frame(camera, np.vstack([np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in framed]), view_direction, size)
    renderer.ResetCameraClippingRange()

    for prop in _annotations(title, legend, lookup, size, camera.GetParallelScale()):
        renderer.AddViewProp(prop)
    write_png(path, renderer, size)


def write_png(path, renderer, size):
    """Render ``renderer`` offscreen with the orientation cube in the corner and write it as a PNG."""
    from vtkmodules.vtkIOImage import vtkPNGWriter
    from vtkmodules.vtkRenderingCore import vtkRenderWindow, vtkWindowToImageFilter

    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(*size)
    window.AddRenderer(renderer)
    window.AddRenderer(_orientation_renderer(renderer.GetActiveCamera()))
    window.Render()
    grabber = vtkWindowToImageFilter()
    grabber.SetInput(window)
    grabber.Update()
    writer = vtkPNGWriter()
    with atomic_path(path) as temporary:  # whole or not at all
        writer.SetFileName(str(temporary))
        writer.SetInputConnection(grabber.GetOutputPort())
        writer.Write()
        window.Finalize()
        if writer.GetErrorCode() or not temporary.is_file() or temporary.stat().st_size == 0:
            raise OSError(f"{path}: writing the PNG failed")


def _frame(camera, points, view_direction, size, margin_mm=25.0):
    """An orthographic camera looking along -``view_direction`` at ``points``, which fill the view but for a
    margin (the legend's band at the top is kept free)."""
    camera.ParallelProjectionOn()
    direction = np.asarray(view_direction, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    up = np.array([0.0, 0.0, 1.0]) - direction[2] * direction
    up /= np.linalg.norm(up)
    right = np.cross(up, direction)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    across = np.ptp(points @ right) + 2 * margin_mm
    along = np.ptp(points @ up) + 2 * margin_mm
    scale = max(along / 2.0, across / 2.0 * size[1] / size[0]) / 0.72  # the scene takes 72 % of the height
    centre = centre + up * 0.18 * scale  # and sits below the title and the legend
    camera.SetFocalPoint(*centre)
    camera.SetPosition(*(centre + direction * 2000.0))
    camera.SetViewUp(*up)
    camera.SetParallelScale(scale)


def _surface_actor(points, triangles):
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    mapper = vtkPolyDataMapper()
    mapper.SetInputData(poly_data(points, triangles))
    actor = vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().SetColor(*BONE_COLOUR)
    if triangles is None or len(triangles) == 0:  # a point cloud: dense round points read as a surface
        actor.GetProperty().SetPointSize(3.0)
        actor.GetProperty().RenderPointsAsSpheresOn()
    else:
        actor.GetProperty().SetOpacity(0.85)
    return actor


def _residual_lookup():
    from vtkmodules.vtkCommonCore import vtkLookupTable

    lookup = vtkLookupTable()
    lookup.SetRange(0.0, RESIDUAL_SCALE_MM)
    lookup.SetHueRange(0.33, 0.0)
    lookup.Build()
    return lookup


def _glyph_actor(centres, radius, colour=None, scalars=None, lookup=None, cube=False):
    """Spheres (or cubes) of ``radius`` mm at ``centres``, in one colour or coloured by ``scalars``."""
    from vtkmodules.vtkCommonCore import vtkDoubleArray
    from vtkmodules.vtkFiltersSources import vtkCubeSource, vtkSphereSource
    from vtkmodules.vtkRenderingCore import vtkActor, vtkGlyph3DMapper

    data = poly_data(np.asarray(centres, dtype=np.float64).reshape(-1, 3))
    if cube:
        source = vtkCubeSource()
        source.SetXLength(2 * radius)
        source.SetYLength(2 * radius)
        source.SetZLength(2 * radius)
    else:
        source = vtkSphereSource()
        source.SetRadius(radius)
        source.SetThetaResolution(24)
        source.SetPhiResolution(24)
    mapper = vtkGlyph3DMapper()
    mapper.SetInputData(data)
    mapper.SetSourceConnection(source.GetOutputPort())
    mapper.ScalingOff()
    if scalars is not None:
        array = vtkDoubleArray()
        array.SetName("residual_mm")
        for value in scalars:
            array.InsertNextValue(float(value))
        data.GetPointData().SetScalars(array)
        mapper.SetLookupTable(lookup)
        mapper.SetScalarRange(0.0, RESIDUAL_SCALE_MM)
    else:
        mapper.ScalarVisibilityOff()
    actor = vtkActor()
    actor.SetMapper(mapper)
    if colour is not None:
        actor.GetProperty().SetColor(*colour)
    return actor


def _cut_actor(cut, ipc_points):
    """A translucent square of the cut plane, 1.4 times the bone's width at the cut."""
    point, normal = (np.asarray(v, dtype=np.float64) for v in cut)
    normal = normal / np.linalg.norm(normal)
    near = np.abs((np.asarray(ipc_points) - point) @ normal) < 1.0
    section = np.asarray(ipc_points)[near] if near.sum() >= 3 else np.asarray(ipc_points)
    half = 0.7 * np.ptp(section - (section - point) @ normal[:, None] * normal, axis=0).max()
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    centre = section.mean(axis=0) - ((section.mean(axis=0) - point) @ normal) * normal
    corner = centre - half * u - half * v
    return patch_actor(corner, corner + 2 * half * u, corner + 2 * half * v, CUT_COLOUR, 0.45)


def patch_actor(corner, first, second, colour, opacity):
    """A translucent parallelogram with corners ``corner``, ``first`` and ``second`` (each (3,), mm)."""
    from vtkmodules.vtkFiltersSources import vtkPlaneSource

    plane = vtkPlaneSource()
    plane.SetOrigin(*corner)
    plane.SetPoint1(*first)
    plane.SetPoint2(*second)
    plane.Update()
    actor = data_actor(plane.GetOutput(), colour)
    actor.GetProperty().SetOpacity(opacity)
    return actor


def data_actor(data, colour):
    """An actor drawing ``vtkPolyData`` in one colour."""
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    mapper = vtkPolyDataMapper()
    mapper.SetInputData(data)
    actor = vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().SetColor(*colour)
    return actor


def _annotations(title, legend, lookup, size, parallel_scale):
    """Title, legend, residual colour bar (when ``lookup`` is given) and a scale bar (2-D props in display
    coordinates)."""
    from vtkmodules.vtkRenderingAnnotation import vtkLegendBoxActor
    from vtkmodules.vtkRenderingCore import vtkTextActor

    width, height = size
    props = []
    heading = vtkTextActor()
    heading.SetInput(title)
    heading.GetTextProperty().SetFontSize(20)
    heading.SetPosition(14, height - 34)
    props.append(heading)

    box = vtkLegendBoxActor()
    box.SetNumberOfEntries(len(legend))
    for index, (label, colour, symbol) in enumerate(legend):
        box.SetEntry(index, _legend_symbol(symbol), label, colour)
    box.GetPositionCoordinate().SetCoordinateSystemToDisplay()
    box.GetPositionCoordinate().SetValue(14, height - 52 - 24 * len(legend))
    box.GetPosition2Coordinate().SetCoordinateSystemToDisplay()
    box.GetPosition2Coordinate().SetValue(360, 22 * len(legend))
    box.GetEntryTextProperty().SetFontSize(15)
    box.GetEntryTextProperty().SetColor(0.92, 0.92, 0.92)
    box.BorderOff()
    box.UseBackgroundOn()
    box.SetBackgroundColor(0.12, 0.13, 0.16)
    box.SetBackgroundOpacity(0.85)
    props.append(box)
    if lookup is not None:
        props.append(_residual_bar(lookup, width))

    # An orthographic view shows 2 * parallel_scale mm over the window's height.
    pixels_per_mm = height / (2.0 * parallel_scale)
    length_mm = next(mm for mm in (100, 50, 20, 10, 5) if mm * pixels_per_mm <= width * 0.25)
    props.extend(_scale_bar(length_mm, length_mm * pixels_per_mm, width))
    return props


def _residual_bar(lookup, width):
    from vtkmodules.vtkRenderingAnnotation import vtkScalarBarActor

    bar = vtkScalarBarActor()
    bar.SetLookupTable(lookup)
    bar.SetTitle("residual (mm)")
    bar.SetNumberOfLabels(5)
    bar.SetLabelFormat("%.2f")
    bar.UnconstrainedFontSizeOn()
    bar.GetTitleTextProperty().SetFontSize(16)
    bar.GetTitleTextProperty().ItalicOff()
    bar.GetLabelTextProperty().SetFontSize(14)
    bar.GetLabelTextProperty().ItalicOff()
    bar.SetVerticalTitleSeparation(12)
    bar.GetPositionCoordinate().SetCoordinateSystemToDisplay()
    bar.GetPositionCoordinate().SetValue(width - 130, 120)
    bar.SetWidth(0.07)
    bar.SetHeight(0.55)
    return bar


def _legend_symbol(kind):
    from vtkmodules.vtkFiltersSources import vtkCubeSource, vtkPlaneSource, vtkSphereSource

    source = {"sphere": vtkSphereSource, "cube": vtkCubeSource, "square": vtkPlaneSource}[kind]()
    source.Update()
    return source.GetOutput()


def _scale_bar(length_mm, length_px, width):
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
    from vtkmodules.vtkRenderingCore import vtkActor2D, vtkPolyDataMapper2D, vtkTextActor

    x0, y0 = width - 60 - length_px, 40
    points = vtkPoints()
    for x, y in ((x0, y0), (x0 + length_px, y0), (x0, y0 - 6), (x0, y0 + 6), (x0 + length_px, y0 - 6)):
        points.InsertNextPoint(x, y, 0.0)
    points.InsertNextPoint(x0 + length_px, y0 + 6, 0.0)
    lines = vtkCellArray()
    for a, b in ((0, 1), (2, 3), (4, 5)):
        lines.InsertNextCell(2)
        lines.InsertCellPoint(a)
        lines.InsertCellPoint(b)
    data = vtkPolyData()
    data.SetPoints(points)
    data.SetLines(lines)
    mapper = vtkPolyDataMapper2D()
    mapper.SetInputData(data)
    bar = vtkActor2D()
    bar.SetMapper(mapper)
    bar.GetProperty().SetColor(1.0, 1.0, 1.0)
    bar.GetProperty().SetLineWidth(2.0)
    label = vtkTextActor()
    label.SetInput(f"{length_mm:g} mm")
    label.GetTextProperty().SetFontSize(16)
    label.GetTextProperty().SetJustificationToCentered()
    label.SetPosition(x0 + length_px / 2.0, y0 + 10)
    return [bar, label]


def _orientation_renderer(camera):
    """A cube labelled with the patient's directions (R/L, A/P, S/I), turned like the main view, lower left."""
    from vtkmodules.vtkRenderingAnnotation import vtkAnnotatedCubeActor
    from vtkmodules.vtkRenderingCore import vtkRenderer

    cube = vtkAnnotatedCubeActor()
    for face, label in zip(("XPlus", "XMinus", "YPlus", "YMinus", "ZPlus", "ZMinus"), "RLAPSI"):
        getattr(cube, f"Set{face}FaceText")(label)
    cube.SetFaceTextScale(0.55)
    cube.GetCubeProperty().SetColor(0.30, 0.33, 0.40)
    cube.GetTextEdgesProperty().SetColor(0.9, 0.9, 0.9)
    for face, colour in (("X", (0.95, 0.45, 0.45)), ("Y", (0.45, 0.9, 0.5)), ("Z", (0.5, 0.65, 1.0))):
        for side in ("Plus", "Minus"):
            getattr(cube, f"Get{face}{side}FaceProperty")().SetColor(*colour)
    corner = vtkRenderer()
    corner.SetBackground(0.12, 0.13, 0.16)
    corner.SetViewport(0.0, 0.0, 0.14, 0.19)
    corner.InteractiveOff()
    corner.AddActor(cube)
    view = corner.GetActiveCamera()
    direction = np.array(camera.GetPosition()) - np.array(camera.GetFocalPoint())
    view.SetFocalPoint(0.0, 0.0, 0.0)
    view.SetPosition(*(direction / np.linalg.norm(direction) * 5.0))
    view.SetViewUp(*camera.GetViewUp())
    corner.ResetCamera()
    return corner
