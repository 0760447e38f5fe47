"""An offscreen picture of a registration (VTK): the IPC surface, the probe points coloured by their residual,
and the marker spheres, as the surgeon sees them in Slicer's 3-D view."""

import numpy as np

from ..io.ndi_tools import MARKER_DIAMETER_MM
from ..io.vtk_arrays import poly_data

#: Residuals from 0 (green) to this (red), mm.
RESIDUAL_SCALE_MM = 1.0


def render_registration(
    path,
    ipc_points,
    ipc_triangles,
    probe_points,
    residuals_mm,
    marker_centres,
    size=(900, 700),
    title="CR-RAMSICP registration",
):
    """Render to a PNG file. All coordinates are image RAS (mm); ``probe_points`` already registered."""
    import vtkmodules.vtkRenderingFreeType  # noqa: F401  (text)
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL back end)
    from vtkmodules.vtkCommonCore import vtkDoubleArray, vtkLookupTable
    from vtkmodules.vtkFiltersSources import vtkSphereSource
    from vtkmodules.vtkIOImage import vtkPNGWriter
    from vtkmodules.vtkRenderingAnnotation import vtkScalarBarActor
    from vtkmodules.vtkRenderingCore import (
        vtkActor,
        vtkGlyph3DMapper,
        vtkPolyDataMapper,
        vtkRenderer,
        vtkRenderWindow,
        vtkTextActor,
        vtkWindowToImageFilter,
    )

    renderer = vtkRenderer()
    renderer.SetBackground(0.12, 0.13, 0.16)
    surface_mapper = vtkPolyDataMapper()
    surface_mapper.SetInputData(poly_data(ipc_points, ipc_triangles))
    surface = vtkActor()
    surface.SetMapper(surface_mapper)
    surface.GetProperty().SetColor(0.89, 0.85, 0.75)
    surface.GetProperty().SetOpacity(0.85)
    renderer.AddActor(surface)

    lookup = vtkLookupTable()
    lookup.SetRange(0.0, RESIDUAL_SCALE_MM)
    lookup.SetHueRange(0.33, 0.0)
    lookup.Build()
    points = poly_data(probe_points)
    scalars = vtkDoubleArray()
    scalars.SetName("residual_mm")
    for value in residuals_mm:
        scalars.InsertNextValue(float(value))
    points.GetPointData().SetScalars(scalars)
    sphere = vtkSphereSource()
    sphere.SetRadius(1.5)
    glyphs = vtkGlyph3DMapper()
    glyphs.SetInputData(points)
    glyphs.SetSourceConnection(sphere.GetOutputPort())
    glyphs.SetLookupTable(lookup)
    glyphs.SetScalarRange(0.0, RESIDUAL_SCALE_MM)
    glyphs.ScalingOff()
    probe = vtkActor()
    probe.SetMapper(glyphs)
    renderer.AddActor(probe)

    marker_sphere = vtkSphereSource()
    marker_sphere.SetRadius(MARKER_DIAMETER_MM / 2.0)
    marker_sphere.SetThetaResolution(24)
    marker_sphere.SetPhiResolution(24)
    marker_glyphs = vtkGlyph3DMapper()
    marker_glyphs.SetInputData(poly_data(marker_centres))
    marker_glyphs.SetSourceConnection(marker_sphere.GetOutputPort())
    marker_glyphs.ScalingOff()
    markers = vtkActor()
    markers.SetMapper(marker_glyphs)
    markers.GetProperty().SetColor(0.55, 0.62, 0.78)
    renderer.AddActor(markers)

    bar = vtkScalarBarActor()
    bar.SetLookupTable(lookup)
    bar.SetTitle("residual (mm)")
    bar.SetNumberOfLabels(3)
    bar.SetWidth(0.08)
    renderer.AddViewProp(bar)
    text = vtkTextActor()
    text.SetInput(title)
    text.GetTextProperty().SetFontSize(18)
    text.SetPosition(12, size[1] - 32)
    renderer.AddViewProp(text)

    camera = renderer.GetActiveCamera()
    centre = np.mean(np.vstack((probe_points, marker_centres)), axis=0)
    camera.SetFocalPoint(*centre)
    camera.SetPosition(*(centre + np.array([-260.0, 320.0, 90.0])))  # antero-medial, slightly above
    camera.SetViewUp(0.0, 0.0, 1.0)
    renderer.ResetCameraClippingRange()
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(*size)
    window.AddRenderer(renderer)
    window.Render()
    grabber = vtkWindowToImageFilter()
    grabber.SetInput(window)
    grabber.Update()
    writer = vtkPNGWriter()
    writer.SetFileName(str(path))
    writer.SetInputConnection(grabber.GetOutputPort())
    writer.Write()
    window.Finalize()
