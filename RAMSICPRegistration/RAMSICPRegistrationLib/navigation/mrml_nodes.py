"""The image side's results as MRML nodes, in a scene passed in (real MRML: Slicer, or ``slicer-core``).

* the segmentation as a ``vtkMRMLSegmentationNode`` (one segment for the bone, one per marker sphere);
* the IPC as a ``vtkMRMLModelNode``;
* the marker centres as a ``vtkMRMLMarkupsFiducialNode`` with 11.5 mm sphere glyphs, which the surgeon can drag
  (the paper's virtual fiducials);
* a CTVolume as a scalar (or labelmap) volume node.

Nothing here reaches for ``slicer.mrmlScene``: every function takes the scene it works on.
"""

import numpy as np

from ..io.ndi_tools import MARKER_DIAMETER_MM
from ..io.vtk_arrays import image_data, poly_data, polyline_data


def volume_node(scene, volume, name, labelmap=False):
    """Add a ``vtkMRMLScalarVolumeNode`` (or ``vtkMRMLLabelMapVolumeNode``) holding a CTVolume's voxels and geometry."""
    node = scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode" if labelmap else "vtkMRMLScalarVolumeNode", name)
    image = image_data(volume.voxels)
    node.SetAndObserveImageData(image)
    node.SetIJKToRASMatrix(_vtk_matrix(volume.ijk_to_ras))
    return node


def segmentation_node(scene, volume, segmentation, spheres=(), name="Bone segmentation"):
    """Add a ``vtkMRMLSegmentationNode`` with a 'bone' segment and a 'marker <n>' segment per marker sphere.

    Args:
        scene: the vtkMRMLScene to add to.
        volume: the segmented CTVolume (its geometry).
        segmentation: BoneSegmentation.
        spheres: the MarkerSpheres found (``number`` names the segment; 0: 'unpaired sphere').
    """
    import slicer

    from ..image.marker_spheres import sphere_labelmap, sphere_values

    labels = type(volume)(voxels=sphere_labelmap(segmentation, spheres), ijk_to_ras=volume.ijk_to_ras)
    labelmap = volume_node(scene, labels, name + " labels", labelmap=True)
    node = scene.AddNewNodeByClass("vtkMRMLSegmentationNode", name)
    if not slicer.vtkSlicerSegmentationsModuleLogic.ImportLabelmapToSegmentationNode(labelmap, node):
        scene.RemoveNode(labelmap)
        raise RuntimeError("Slicer could not import the bone labelmap into a segmentation node")
    scene.RemoveNode(labelmap)
    # Slicer makes one segment per label value, in increasing order: 1 the bone, 1 + n marker n.
    named = {
        1: "bone",
        **{
            value: f"marker {s.number}" if s.number else "unpaired sphere"
            for value, s in zip(sphere_values(spheres), spheres)
        },
    }
    names = [named[value] for value in sorted(named)]
    segments = node.GetSegmentation()
    for index, segment_name in enumerate(names[: segments.GetNumberOfSegments()]):
        segments.GetNthSegment(index).SetName(segment_name)
    return node


def model_node(scene, points, triangles=None, name="IPC"):
    """Add a ``vtkMRMLModelNode`` of the IPC: RAS points (M, 3), and triangles (K, 3) or none (a point cloud)."""
    node = scene.AddNewNodeByClass("vtkMRMLModelNode", name)
    node.SetAndObservePolyData(poly_data(points, triangles))
    node.CreateDefaultDisplayNodes()
    return node


def polyline_model(scene, points, name):
    """Add a ``vtkMRMLModelNode`` of one polyline through (N, 3) RAS points (a tool path), drawn as a line."""
    node = scene.AddNewNodeByClass("vtkMRMLModelNode", name)
    node.SetAndObservePolyData(polyline_data(points))
    node.CreateDefaultDisplayNodes()
    node.GetDisplayNode().SetLineWidth(2.0)
    return node


def glyph_fiducial_node(scene, name, glyph="Sphere3D", size_mm=MARKER_DIAMETER_MM, colour=None):
    """Add an empty ``vtkMRMLMarkupsFiducialNode`` whose points are drawn as ``glyph`` of ``size_mm`` (absolute size,
    not scaled with the view), in ``colour`` (r, g, b in 0-1) when given, selected or not."""
    node = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", name)
    node.CreateDefaultDisplayNodes()
    display = node.GetDisplayNode()
    if colour is not None:
        display.SetSelectedColor(*colour)
        display.SetColor(*colour)
    display.SetGlyphTypeFromString(glyph)
    display.SetUseGlyphScale(False)
    display.SetGlyphSize(size_mm)
    return node


def fiducial_node(scene, centres, labels=None, name="Marker centres (image)"):
    """Add a ``vtkMRMLMarkupsFiducialNode`` of marker centres (K, 3) RAS, drawn as 11.5 mm spheres."""
    node = glyph_fiducial_node(scene, name)
    labels = labels or [f"M{number + 1}" for number in range(len(centres))]
    for centre, label in zip(np.asarray(centres, dtype=np.float64), labels):
        node.AddControlPoint(centre.tolist(), label)
    return node


def fiducial_positions(node):
    """Control-point positions (K, 3) RAS of a markups node, e.g. after the surgeon moved them."""
    return np.array([node.GetNthControlPointPosition(i) for i in range(node.GetNumberOfControlPoints())]).reshape(-1, 3)


def _vtk_matrix(array):
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    for row in range(4):
        for column in range(4):
            matrix.SetElement(row, column, float(array[row][column]))
    return matrix
