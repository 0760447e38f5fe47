"""Iso-surfaces of 3-D arrays (VTK's flying edges), shared by the bone surface and the marker-sphere fit."""


def iso_surface(image, level):
    """Iso-surface of a 3-D array at ``level`` (VTK flying edges): vertices (M, 3) in index units, triangles (K, 3)."""
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D

    from ..io.vtk_arrays import image_data, triangle_arrays

    edges = vtkFlyingEdges3D()
    edges.SetInputData(image_data(image))
    edges.SetValue(0, float(level))
    edges.ComputeNormalsOff()
    edges.ComputeGradientsOff()
    edges.ComputeScalarsOff()
    edges.Update()
    return triangle_arrays(edges.GetOutput())
