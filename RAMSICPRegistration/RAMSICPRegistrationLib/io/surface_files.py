"""Surfaces on disk (``.vtk`` ``.vtp`` ``.stl`` ``.ply`` ``.obj``) read and written with VTK.

The frame follows Slicer's model storage: a ``SPACE=LPS``/``SPACE=RAS`` tag in the file header (legacy VTK,
STL), a PLY or OBJ comment, or a ``SPACE`` string in a VTP's field data. Untagged files are taken to be in
``untagged_space`` (RAS unless told; note that Slicer assumes LPS for them). Files are written in LPS with the
tag, as Slicer writes them.
"""

from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .atomic_files import atomic_path
from .file_checks import PointFileError, check_input_file
from .point_files import POINT_SUFFIXES, _check_space, _suffix, read_points, to_ras
from .vtk_arrays import poly_data

SURFACE_SUFFIXES = (".vtk", ".vtp", ".stl", ".ply", ".obj")


def read_surface_points(path, untagged_space="RAS", with_space=False):
    """IPC points (M, 3) in RAS mm from a surface (its vertices) or from a point file; with ``with_space``, also the
    frame the file stated ('RAS', 'LPS', or None when it stated none)."""
    path = Path(path)
    if _suffix(path) in POINT_SUFFIXES:
        point_set = read_points(path, untagged_space)
        return (point_set.points, point_set.stated_space) if with_space else point_set.points
    vertices, _, stated = read_surface_mesh(path, untagged_space, with_space=True)
    return (vertices, stated) if with_space else vertices


def read_surface_mesh(path, untagged_space="RAS", with_space=False):
    """Vertices (M, 3) RAS mm and triangles (K, 3) vertex indices of a surface file (with ``with_space``, also the
    frame its header stated, or None).

    Polygons are triangulated; a file with vertices but no polygons gives an empty (0, 3) triangle array.

    Raises:
        PointFileError: a missing or empty file, a folder, an unknown type, an unreadable file or one without points.
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkFiltersCore import vtkTriangleFilter

    untagged_space = _check_space(untagged_space)
    path = check_input_file(path, "surface file")
    suffix = _suffix(path)
    if suffix not in SURFACE_SUFFIXES:
        raise PointFileError(path, f"unknown surface type; use one of {', '.join(SURFACE_SUFFIXES)}")
    reader, header_of = _reader(suffix)
    errors = _collect_errors(reader)
    reader.SetFileName(str(path))
    with _vtk_console_silenced():
        reader.Update()
    mesh = reader.GetOutput()
    if errors or mesh is None or mesh.GetNumberOfPoints() == 0:
        detail = errors[0].strip().splitlines()[-1] if errors else "no points in it"
        raise PointFileError(path, f"cannot read as {suffix[1:].upper()} surface ({detail})")
    stated = _space_from_text(header_of(reader, mesh))
    space = stated or untagged_space
    vertices = to_ras(vtk_to_numpy(mesh.GetPoints().GetData()).astype(np.float64), space)
    if not np.isfinite(vertices).all():
        raise PointFileError(path, "contains NaN or infinite coordinates")
    triangles = np.zeros((0, 3), dtype=np.int64)
    if mesh.GetNumberOfPolys() > 0:
        triangulate = vtkTriangleFilter()
        triangulate.SetInputData(mesh)
        triangulate.PassVertsOff()
        triangulate.PassLinesOff()
        triangulate.Update()
        cells = triangulate.GetOutput().GetPolys()
        triangles = vtk_to_numpy(cells.GetConnectivityArray()).reshape(-1, 3).astype(np.int64)
    return (vertices, triangles, stated) if with_space else (vertices, triangles)


def write_surface(path, vertices, triangles=None):
    """Write RAS vertices (M, 3) and optional triangles (K, 3) as a surface in LPS, tagged as Slicer does.

    Without triangles every vertex is written as a vertex cell, so the file is a point cloud.
    """
    from vtkmodules.vtkCommonCore import vtkStringArray

    path = Path(path)
    suffix = _suffix(path)
    if suffix not in SURFACE_SUFFIXES:
        raise PointFileError(path, f"unknown surface type; use one of {', '.join(SURFACE_SUFFIXES)}")
    mesh = poly_data(to_ras(np.asarray(vertices, dtype=np.float64), "LPS"), triangles)
    writer = _writer(suffix)
    if suffix == ".vtp":
        tag = vtkStringArray()
        tag.SetName("SPACE")
        tag.InsertNextValue("LPS")
        mesh.GetFieldData().AddArray(tag)
    elif suffix in (".vtk", ".stl"):
        writer.SetHeader("SPACE=LPS")
    elif suffix == ".ply":
        writer.AddComment("SPACE=LPS")
    errors = _collect_errors(writer)
    with atomic_path(path) as temporary:  # whole or not at all
        writer.SetFileName(str(temporary))
        writer.SetInputData(mesh)
        with _vtk_console_silenced():
            written = writer.Write()
        if not written or errors:
            raise PointFileError(path, f"cannot write ({errors[0].strip() if errors else 'writer failed'})")
        if suffix == ".obj":
            # vtkOBJWriter writes no header comment; put the tag where Slicer's reader looks for it.
            temporary.write_text("# SPACE=LPS\n" + temporary.read_text(encoding="utf-8"), encoding="utf-8")


def _reader(suffix):
    if suffix == ".vtk":
        from vtkmodules.vtkIOLegacy import vtkPolyDataReader

        return vtkPolyDataReader(), lambda reader, mesh: reader.GetHeader()
    if suffix == ".vtp":
        from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

        return vtkXMLPolyDataReader(), _space_from_field_data
    if suffix == ".stl":
        from vtkmodules.vtkIOGeometry import vtkSTLReader

        return vtkSTLReader(), lambda reader, mesh: reader.GetHeader()
    if suffix == ".ply":
        from vtkmodules.vtkIOPLY import vtkPLYReader

        return vtkPLYReader(), _ply_comments
    from vtkmodules.vtkIOGeometry import vtkOBJReader

    return vtkOBJReader(), lambda reader, mesh: reader.GetComment()


def _writer(suffix):
    if suffix == ".vtk":
        from vtkmodules.vtkIOLegacy import vtkPolyDataWriter

        return vtkPolyDataWriter()
    if suffix == ".vtp":
        from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

        return vtkXMLPolyDataWriter()
    if suffix == ".stl":
        from vtkmodules.vtkIOGeometry import vtkSTLWriter

        writer = vtkSTLWriter()
        writer.SetFileTypeToBinary()
        return writer
    if suffix == ".ply":
        from vtkmodules.vtkIOPLY import vtkPLYWriter

        return vtkPLYWriter()
    from vtkmodules.vtkIOGeometry import vtkOBJWriter

    return vtkOBJWriter()


def _space_from_field_data(reader, mesh):
    array = mesh.GetFieldData().GetAbstractArray("SPACE")
    return array.GetValue(0) if array is not None and array.GetNumberOfValues() else None


def _ply_comments(reader, mesh):
    comments = reader.GetComments()
    return " ".join(comments.GetValue(i) for i in range(comments.GetNumberOfValues()))


def _space_from_text(text):
    if not text:
        return None
    for space in ("RAS", "LPS"):
        if f"SPACE={space}" in text or text.strip() == space:
            return space
    return None


def _collect_errors(algorithm):
    """Route VTK's error events into a list (instead of the console) and return that list."""
    from vtkmodules.util.misc import calldata_type
    from vtkmodules.util.vtkConstants import VTK_STRING

    errors = []

    @calldata_type(VTK_STRING)
    def on_error(caller, event, message):
        errors.append(str(message))

    algorithm.AddObserver("ErrorEvent", on_error)
    return errors


@contextmanager
def _vtk_console_silenced():
    """Keep VTK's pipeline chatter about a bad file off the console; the error itself reaches the caller."""
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    previous_window = vtkOutputWindow.GetInstance()
    previous_verbosity = vtkLogger.GetCurrentVerbosityCutoff()
    vtkOutputWindow.SetInstance(vtkStringOutputWindow())
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    try:
        yield
    finally:
        vtkLogger.SetStderrVerbosity(previous_verbosity)
        vtkOutputWindow.SetInstance(previous_window)
