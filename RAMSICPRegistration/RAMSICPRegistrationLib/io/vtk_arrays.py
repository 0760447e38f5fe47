"""numpy arrays to VTK data objects and back, in one place: image data from (I, J, K) arrays, poly data from
points and triangles or a polyline, and a triangle mesh's points and triangles from poly data."""

import numpy as np


def image_data(array):
    """``vtkImageData`` of an (I, J, K) array in index space (origin 0, spacing 1); VTK runs i fastest."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData

    image = vtkImageData()
    image.SetDimensions(*array.shape)
    image.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(array.transpose(2, 1, 0)).ravel(), deep=True))
    return image


def poly_data(points, triangles=None):
    """``vtkPolyData`` of (M, 3) points with (K, 3) triangles, or with one vertex cell per point (a cloud)."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    vtk_points = vtkPoints()
    vtk_points.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    mesh = vtkPolyData()
    mesh.SetPoints(vtk_points)
    cloud = triangles is None or len(triangles) == 0
    if cloud:
        offsets, connectivity = np.arange(len(points) + 1), np.arange(len(points))
    else:
        offsets, connectivity = np.arange(0, 3 * len(triangles) + 1, 3), np.asarray(triangles).ravel()
    cells = vtkCellArray()
    cells.SetData(
        numpy_to_vtkIdTypeArray(np.ascontiguousarray(offsets, dtype=np.int64), deep=True),
        numpy_to_vtkIdTypeArray(np.ascontiguousarray(connectivity, dtype=np.int64), deep=True),
    )
    if cloud:
        mesh.SetVerts(cells)
    else:
        mesh.SetPolys(cells)
    return mesh


def polyline_data(points):
    """``vtkPolyData`` of one polyline through (N, 3) points, in their order (a tool path)."""
    from vtkmodules.vtkCommonDataModel import vtkCellArray

    data = poly_data(points)
    data.SetVerts(vtkCellArray())
    line = vtkCellArray()
    line.InsertNextCell(len(points))
    for index in range(len(points)):
        line.InsertCellPoint(index)
    data.SetLines(line)
    return data


def triangle_arrays(mesh):
    """Vertices (M, 3) float64 and triangles (K, 3) int64 of a ``vtkPolyData`` whose polygons are triangles."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if mesh.GetNumberOfPoints() == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    vertices = vtk_to_numpy(mesh.GetPoints().GetData()).astype(np.float64)
    triangles = vtk_to_numpy(mesh.GetPolys().GetConnectivityArray()).reshape(-1, 3).astype(np.int64)
    return vertices, triangles


def mesh_inside_grid(vertices_ijk, triangles, shape):
    """(I, J, K) booleans: which voxel centres of a grid of ``shape`` lie inside a closed triangle mesh whose (M, 3)
    vertices are given in that grid's index coordinates (voxel (0, 0, 0) at the origin), scan line by scan line
    (VTK's ``vtkPolyDataToImageStencil``)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkImagingStencil import vtkImageStencilToImage, vtkPolyDataToImageStencil

    shape = np.asarray(shape, dtype=int)
    stencil = vtkPolyDataToImageStencil()
    stencil.SetInputData(poly_data(vertices_ijk, triangles))
    stencil.SetOutputOrigin(0.0, 0.0, 0.0)
    stencil.SetOutputSpacing(1.0, 1.0, 1.0)
    stencil.SetOutputWholeExtent(0, shape[0] - 1, 0, shape[1] - 1, 0, shape[2] - 1)
    to_image = vtkImageStencilToImage()
    to_image.SetInputConnection(stencil.GetOutputPort())
    to_image.SetInsideValue(1)
    to_image.SetOutsideValue(0)
    to_image.SetOutputScalarTypeToUnsignedChar()
    to_image.Update()
    scalars = vtk_to_numpy(to_image.GetOutput().GetPointData().GetScalars())
    return scalars.reshape(shape[::-1]).transpose(2, 1, 0).astype(bool)
