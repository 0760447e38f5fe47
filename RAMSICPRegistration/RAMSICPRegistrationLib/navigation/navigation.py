"""The workflow's steps on MRML nodes passed in (no Qt, no globals); ``controller.NavigationController`` drives them.

Steps, as in the module's GUI: (1) image: CT -> segmentation, IPC model, marker fiducials; (2) tracker: the
transform hierarchy ``ProbeTipToProbe -> ProbeToReference -> ReferenceToImage`` and pivot calibration;
(3) patient points: marker centres in reference coordinates and probe points, each saved at once; (4) register:
CR / CR-ICP / CR-RAMSICP, the result as the ``ReferenceToImage`` transform, a residual table with an include
column, and a plot of the sweep; (5) verify: target TRE and the live tip-to-surface distance; (6) robot: eqs.
3-4; (7) save and reload the scene. It works on any real MRML scene: Slicer's, or ``slicer-core``'s.

Each step records the nodes it writes in the module's parameter node (``parameters.PARAMETERS``), so later steps
and every shell find them by reference, never by name. What follows a tracked tool over time (stale detection,
pivot recording, auto-collect, live readouts) lives in the controller, which observes the nodes' events.
"""

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.coarse_checks import check_reference_frame
from ..core.pivot import pivot_calibration
from ..core.registration import DEFAULT_METHOD, register
from ..core.robot import image_to_robot_base, robot_base_to_tracker
from ..core.surface_index import SurfaceIndex
from ..core.transforms import apply_transform
from ..image.ct_pipeline import NoBoneSurface, process_ct
from ..image.ct_segmentation import DEFAULT_THRESHOLD_HU
from ..image.hounsfield import check_bone_threshold, check_hounsfield_units
from ..image.volume_io import load_volume
from ..io.marker_files import flagged_message, labelled_markers, marker_label, pair_marker_sets
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL, tool_marker_geometry
from ..io.point_files import write_points_atomic
from . import mrml_nodes
from .parameters import Parameters, get_parameter_node

logger = logging.getLogger(__name__)


#: The markups node holding the marker spheres of a CT that gave no IPC (no bone in it).
REFUSED_CT_MARKERS = "MarkersImage (CT without IPC)"


@dataclass(frozen=True)
class ImageSideNodes:
    """The image step's nodes and the marker detection's warnings."""

    segmentation: object
    ipc_model: object
    markers_image: object
    warnings: tuple


def matrix_of(node, name="transform node"):
    """(4, 4) matrix to parent of a linear ``vtkMRMLTransformNode``; raises TypeError/ValueError on a wrong node."""
    if node is None or not (hasattr(node, "IsA") and node.IsA("vtkMRMLTransformNode")):
        raise TypeError(f"{name}: expected a linear transform node, got {type(node).__name__}")
    if not node.IsLinear():
        raise ValueError(f"{name} {node.GetName()!r} is not linear; use a linear transform node")
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    node.GetMatrixTransformToParent(matrix)
    return np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])


def set_matrix(node, matrix):
    """Write a (4, 4) matrix into a linear transform node (as its transform to parent)."""
    node.SetMatrixTransformToParent(mrml_nodes._vtk_matrix(matrix))


def points_of(node, name="point list"):
    """(N, 3) RAS positions of a markups node, or the points of a model node."""
    if node is None:
        raise ValueError(f"{name}: no node selected; pick one")
    if node.IsA("vtkMRMLMarkupsNode"):
        return mrml_nodes.fiducial_positions(node)
    if node.IsA("vtkMRMLModelNode"):
        from vtkmodules.util.numpy_support import vtk_to_numpy

        data = node.GetPolyData()
        if data is None or data.GetNumberOfPoints() == 0:
            raise ValueError(f"{name} {node.GetName()!r} has no points; build the IPC from the CT first")
        return vtk_to_numpy(data.GetPoints().GetData()).astype(np.float64)
    raise TypeError(f"{name}: expected a markups or model node, got {node.GetClassName()}")


class NavigationLogic:
    """The workflow's steps on one MRML scene.

    Args:
        scene: the vtkMRMLScene (``slicer.mrmlScene`` inside Slicer).
        autosave_directory: every collected point list is written here at once (``<node name>.mrk.json``).

    ``image_processor`` is what ``process_ct`` runs on the CT: ``image.ct_pipeline.process_ct``, or a function with
    its signature and result (the browser demo sets ``image_side_cache.cached_image_side``).
    """

    image_processor = staticmethod(process_ct)

    def __init__(self, scene, autosave_directory=None):
        self.scene = scene
        self.autosave_directory = None if autosave_directory is None else Path(autosave_directory)
        self._index_cache = (None, None, None)

    # -- parameters ---------------------------------------------------------------------------------------
    @property
    def parameter_node(self):
        """The module's singleton ``vtkMRMLScriptedModuleNode``; saved and reloaded with the scene."""
        return get_parameter_node(self.scene)

    @property
    def parameters(self):
        """Typed access to the parameter node (``parameters.Parameters``)."""
        return Parameters(self.parameter_node)

    def transform_node(self, name):
        """The linear transform node called ``name``, created once, then reused (as SlicerOpenIGTLink does)."""
        node = self.scene.GetFirstNodeByName(name)
        if node is None:
            node = self.scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", name)
        return node

    # -- 1. image ------------------------------------------------------------------------------------------
    def process_ct(self, volume_node, threshold_hu=DEFAULT_THRESHOLD_HU, tool_id=DEFAULT_REFERENCE_TOOL, progress=None):
        """CT volume node -> segmentation node, IPC model node and marker-centre fiducials (image, tool order).

        ``progress(step, done, total)`` is called between the steps; an exception it raises (a cancel) stops the
        run before any node is written. Nodes written by an earlier run are replaced.
        """
        if not isinstance(threshold_hu, str):
            check_bone_threshold(threshold_hu)  # a fraction or a soft-tissue threshold, before any work
        volume = load_volume(volume_node)
        check_hounsfield_units(volume.voxels, threshold_hu)
        tool = tool_marker_geometry(tool_id)
        try:
            image = self.image_processor(volume, threshold_hu, tool_markers=tool, progress=progress)
        except NoBoneSurface as error:
            # No IPC, but the marker centres found are the user's: in a node of their own (an earlier run's nodes,
            # which the workflow uses, are left as they were).
            node = self._marker_node(error.detection.spheres, name=REFUSED_CT_MARKERS)
            raise ValueError(
                f"{error}; {error.spheres_found(len(tool))} are in the markups node '{node.GetName()}'"
            ) from error
        segmentation, surface, spheres = image.segmentation, image.surface, image.spheres
        parameters = self.parameters
        for old in (parameters.segmentation, parameters.ipcModel, parameters.markersImage):
            if old is not None:
                self.scene.RemoveNode(old)
        segmentation_node = mrml_nodes.segmentation_node(self.scene, volume, segmentation, spheres)
        ipc = mrml_nodes.model_node(self.scene, surface.points, surface.triangles, name="IPC")
        markers = self._marker_node(spheres)
        parameters.ctVolume = volume_node
        parameters.thresholdHU = segmentation.threshold_hu
        parameters.segmentation, parameters.ipcModel, parameters.markersImage = segmentation_node, ipc, markers
        return ImageSideNodes(segmentation_node, ipc, markers, image.warnings)

    def _marker_node(self, spheres, name="MarkersImage"):
        """A fiducial node of the spheres found, labelled M<n> <status> as ``ramsicp ipc`` writes them."""
        return mrml_nodes.fiducial_node(
            self.scene,
            np.array([s.centre for s in spheres]).reshape(-1, 3),
            [marker_label(s.number, s.status) for s in spheres],
            name=name,
        )

    # -- 2. tracker ----------------------------------------------------------------------------------------
    def build_hierarchy(self, probe_tip_to_probe, probe_to_reference, reference_to_image):
        """Chain ``ProbeTipToProbe -> ProbeToReference -> ReferenceToImage`` so the tracked tip moves over the CT."""
        for node, name in (
            (probe_tip_to_probe, "ProbeTipToProbe"),
            (probe_to_reference, "ProbeToReference"),
            (reference_to_image, "ReferenceToImage"),
        ):
            matrix_of(node, name)
        probe_tip_to_probe.SetAndObserveTransformNodeID(probe_to_reference.GetID())
        probe_to_reference.SetAndObserveTransformNodeID(reference_to_image.GetID())

    def pivot_calibrate(self, probe_to_reference_poses, probe_tip_to_probe):
        """Pivot calibration from recorded (N, 4, 4) ProbeToReference poses; writes ``ProbeTipToProbe``."""
        result = pivot_calibration(probe_to_reference_poses)
        set_matrix(probe_tip_to_probe, result.probe_tip_to_probe)
        self.parameter_node.SetParameter("PivotRmsMm", f"{result.rms_mm:.6g}")
        return result

    def tip_in_reference(self, probe_to_reference, probe_tip_to_probe):
        """Probe-tip position (3,) in reference coordinates: ProbeToReference @ ProbeTipToProbe @ origin (eq. 2)."""
        tip = matrix_of(probe_to_reference, "ProbeToReference") @ matrix_of(probe_tip_to_probe, "ProbeTipToProbe")
        return tip[:3, 3].copy()

    # -- 3. patient points ---------------------------------------------------------------------------------
    def markers_patient_node(self, tool_id=DEFAULT_REFERENCE_TOOL):
        """Fiducials of the reference body's marker centres in reference coordinates, from the NDI tool geometry."""
        node = mrml_nodes.fiducial_node(self.scene, tool_marker_geometry(tool_id), name="MarkersPatient")
        self.parameters.markersPatient = node
        return node

    def collect_point(self, points_node, probe_to_reference, probe_tip_to_probe, min_distance_mm=None):
        """Add the current tip position (reference coordinates) to ``points_node`` and save the list at once.

        With ``min_distance_mm`` (auto-collect) the point is only added if it lies at least that far from the
        last one. Returns the new point's index, or None when auto-collect skipped it. Whether the tracker is
        still sending is the caller's to check (the controller does, from the nodes' events).
        """
        tip = self.tip_in_reference(probe_to_reference, probe_tip_to_probe)
        count = points_node.GetNumberOfControlPoints()
        if min_distance_mm is not None and count:
            last = np.array(points_node.GetNthControlPointPosition(count - 1))
            if np.linalg.norm(tip - last) < min_distance_mm:
                return None
        return self.add_point(points_node, tip)

    def add_point(self, points_node, position):
        """Add ``position`` (3,) in reference coordinates (mm) as the next point ``P<n>`` and save the list at once;
        returns its index."""
        count = points_node.GetNumberOfControlPoints()
        points_node.AddControlPoint(np.asarray(position, dtype=np.float64).tolist(), f"P{count + 1}")
        self.autosave(points_node)
        return count

    def autosave(self, node):
        """Write a point list to the autosave folder at once, atomically (``<node name>.mrk.json``)."""
        if self.autosave_directory is None:
            return
        positions = mrml_nodes.fiducial_positions(node)
        labels = [node.GetNthControlPointLabel(i) for i in range(len(positions))]
        write_points_atomic(self.autosave_directory / f"{node.GetName()}.mrk.json", positions, labels)

    # -- 4. register ---------------------------------------------------------------------------------------
    def register(
        self,
        ipc_node,
        ppc_node,
        markers_image_node,
        markers_patient_node,
        targets_image_node=None,
        targets_patient_node=None,
        method=DEFAULT_METHOD,
        sweep=True,
        scale=None,
        policy=None,
    ):
        """Register and write the results into the scene, ReferenceToImage only when the result has no alarms
        (``apply_registration`` writes it for one the user accepted).

        Probe points whose 'include' cell in the residual table is off are left out. Probe points far from the bone
        after the CR are left out too (``core.coarse_checks``), their 'include' cell turned off and their 'note'
        saying so, unless the user turned 'include' back on for such a point: it is then used. The markers are
        paired by their numbers, checked by their distances (``pair_marker_sets``). Writes the
        ``RegistrationResiduals`` table, the ``RegistrationSweep`` plot and the figures into the parameter node.
        Raises ValueError/TypeError with what to do.
        """
        ipc = points_of(ipc_node, "IPC model")
        ppc_all = points_of(ppc_node, "probe points")
        include = self._included(len(ppc_all))
        rows = np.flatnonzero(include)
        hand_included = self._far_included(len(ppc_all))  # far after an earlier CR, included again by the user
        include_far = [position for position, row in enumerate(rows) if hand_included[row]]
        if include.sum() < 3:
            raise ValueError(f"only {include.sum()} probe points are included; include or collect at least 3")
        markers_image, markers_patient, pairing_warnings = _paired_markers(markers_image_node, markers_patient_node)
        check_reference_frame(ppc_all[include], "probe points")
        check_reference_frame(
            markers_patient,
            "marker centres (patient)",
            tool_marker_geometry(DEFAULT_REFERENCE_TOOL),
            "the reference body",
        )
        if min(len(markers_image), len(markers_patient)) < 3:
            raise ValueError(
                "the coarse registration needs at least 3 marker centres in both the image and the "
                "patient; detect or place the missing ones"
            )
        targets = [None, None]  # image targets alone give the predicted error there (the plan's endpoints)
        if targets_image_node is not None and targets_image_node.GetNumberOfControlPoints():
            targets[0] = points_of(targets_image_node, "targets (image)")
            if targets_patient_node is not None:
                targets[1] = points_of(targets_patient_node, "targets (patient)")
        result = register(
            self._index(ipc_node, ipc),
            ppc_all[include],
            markers_image,
            markers_patient,
            targets[0],
            targets[1],
            method=method,
            sweep=sweep and method == "cr-ramsicp",
            scale=scale if method == "cr-ramsicp" else None,
            policy=policy,
            include_far=include_far,
        )
        if pairing_warnings:
            result = replace(
                result, warnings=tuple(result.alarms) + pairing_warnings + result.warnings[len(result.alarms) :]
            )
        parameters = self.parameters
        if not result.alarms:  # a result with alarms is applied only when the user accepts it (the controller)
            self.apply_registration(result)
        parameters.probePoints = ppc_node
        residuals = np.full(len(ppc_all), np.nan)
        residuals[include] = result.residuals_mm
        notes = self._notes() if len(self._notes()) == len(ppc_all) else [""] * len(ppc_all)
        for row in rows:  # a point left out by the user keeps its note; the others get this registration's
            notes[row] = ""
        for position in result.far_points:
            notes[rows[position]] = f"far from the bone after the CR: {result.coarse_distances_mm[position]:.1f} mm"
        include[rows[list(result.left_out)]] = False
        self._write_residual_table(ppc_node, ppc_all, residuals, include)
        self._write_notes(notes)
        if result.sweep:
            self._write_sweep_plot(result)
        for key, value in (
            ("Method", method),
            ("Scale", result.scale),
            ("ScalePolicy", result.scale_policy),
            ("FreMm", result.fre_mm),
            ("PpcRmsMm", result.ppc_rms_mm),
            ("TreMm", result.tre_mm),
            ("Warnings", "\n".join(result.warnings)),
        ):  # the result's figures, saved with the scene
            parameters.node.SetParameter(key, "" if value is None else str(value))
        return result

    def apply_registration(self, result):
        """Write ``result.reference_to_image`` into ReferenceToImage (created when missing): navigation uses it."""
        parameters = self.parameters
        reference_to_image = parameters.referenceToImage or self.transform_node("ReferenceToImage")
        set_matrix(reference_to_image, result.reference_to_image)
        parameters.referenceToImage = reference_to_image

    def far_points(self):
        """Probe points (numbered from 1) that lay far from the bone after the last registration's CR."""
        notes = self._notes()
        return [row + 1 for row, note in enumerate(notes) if note.startswith("far")]

    def _notes(self):
        table = self.parameters.residualTable
        column = None if table is None else table.GetTable().GetColumnByName("note")
        if column is None:
            return []
        return [str(column.GetValue(row)) for row in range(column.GetNumberOfTuples())]

    def _far_included(self, count):
        """(count,) booleans: points the last registration found far whose 'include' the user turned back on."""
        notes, include = self._notes(), self._included(count)
        if len(notes) != count:
            return np.zeros(count, dtype=bool)
        return np.array([note.startswith("far") for note in notes]) & include

    def _write_notes(self, notes):
        """The residual table's 'note' column: why a point is flagged ('' for none)."""
        from vtkmodules.vtkCommonCore import vtkStringArray

        column = vtkStringArray()
        column.SetName("note")
        for note in notes:
            column.InsertNextValue(note)
        table = self.parameters.residualTable.GetTable()
        table.RemoveColumnByName("note")
        table.AddColumn(column)
        table.Modified()

    def surface_index(self, ipc_node):
        """The IPC model's SurfaceIndex (image coordinates), built once per state of its surface."""
        return self._index(ipc_node, None)

    def _index(self, ipc_node, ipc):
        """The KD-tree of the IPC (its points ``ipc``, or read from the node when None), rebuilt only when the IPC
        model changed."""
        key = (ipc_node.GetID(), ipc_node.GetPolyData().GetMTime())
        if self._index_cache[0] != key:
            points = points_of(ipc_node, "IPC model") if ipc is None else ipc
            self._index_cache = (key, SurfaceIndex(points), ipc_node)
        return self._index_cache[1]

    def _included(self, count):
        table = self.parameters.residualTable
        if table is None or table.GetNumberOfRows() != count:
            return np.ones(count, dtype=bool)
        column = table.GetTable().GetColumnByName("include")
        return np.array([bool(column.GetValue(row)) for row in range(count)])

    def set_included(self, point_index, included):
        """Include or exclude one probe point from the next registration (the table's 'include' cell)."""
        table = self.parameters.residualTable
        if table is None:
            raise ValueError("no residual table yet; register once first")
        if not 0 <= point_index < table.GetNumberOfRows():
            raise ValueError(f"point {point_index + 1}: the table has points 1 to {table.GetNumberOfRows()}")
        table.GetTable().GetColumnByName("include").SetValue(point_index, int(bool(included)))
        table.GetTable().Modified()

    def _write_residual_table(self, ppc_node, ppc, residuals, include):
        """The ``RegistrationResiduals`` table: point label, x, y, z (reference, mm), residual (mm; NaN when left
        out) and 'include', a ``vtkBitArray``: Slicer's table view (qMRMLTableModel) shows a bit column as tick
        boxes and writes a click back into it; any other integer column shows as 0/1 text."""
        from vtkmodules.vtkCommonCore import vtkBitArray, vtkDoubleArray, vtkStringArray
        from vtkmodules.vtkCommonDataModel import vtkTable

        table = vtkTable()
        labels = vtkStringArray()
        labels.SetName("point")
        columns = {name: vtkDoubleArray() for name in ("x", "y", "z", "residual_mm")}
        for name, array in columns.items():
            array.SetName(name)
        included = vtkBitArray()
        included.SetName("include")
        for row in range(len(ppc)):
            labels.InsertNextValue(ppc_node.GetNthControlPointLabel(row))
            for axis, name in enumerate(("x", "y", "z")):
                columns[name].InsertNextValue(ppc[row, axis])
            columns["residual_mm"].InsertNextValue(residuals[row])
            included.InsertNextValue(int(include[row]))
        for array in (labels, *columns.values(), included):
            table.AddColumn(array)
        parameters = self.parameters
        node = parameters.residualTable or self.scene.AddNewNodeByClass("vtkMRMLTableNode", "RegistrationResiduals")
        node.SetAndObserveTable(table)
        parameters.residualTable = node

    def _write_sweep_plot(self, result):
        from vtkmodules.vtkCommonCore import vtkDoubleArray
        from vtkmodules.vtkCommonDataModel import vtkTable

        table = vtkTable()
        names = ["L", "rms_mm"] + (["tre_mm"] if result.sweep[0].tre_mm is not None else [])
        for name in names:
            array = vtkDoubleArray()
            array.SetName(name)
            for entry in result.sweep:
                value = {"L": entry.scale, "rms_mm": entry.result.rms_mm, "tre_mm": entry.tre_mm}[name]
                array.InsertNextValue(value)
            table.AddColumn(array)
        parameters = self.parameters
        chart = parameters.sweepChart
        if chart is None:
            chart = self.scene.AddNewNodeByClass("vtkMRMLPlotChartNode", "RegistrationSweep")
            chart.SetXAxisTitle("scale factor L")
            chart.SetYAxisTitle("mm")
            parameters.sweepChart = chart
        series_by_column = {}
        for index in range(chart.GetNumberOfPlotSeriesNodes()):
            series = chart.GetNthPlotSeriesNode(index)
            series_by_column[series.GetYColumnName()] = series
        table_node = next((s.GetTableNode() for s in series_by_column.values() if s.GetTableNode()), None)
        if table_node is None:
            table_node = self.scene.AddNewNodeByClass("vtkMRMLTableNode", "RegistrationSweepTable")
        table_node.SetAndObserveTable(table)
        for name in names[1:]:
            series = series_by_column.get(name)
            if series is None:
                series = self.scene.AddNewNodeByClass("vtkMRMLPlotSeriesNode", f"RegistrationSweep {name}")
                chart.AddAndObservePlotSeriesNodeID(series.GetID())
            series.SetAndObserveTableNodeID(table_node.GetID())
            series.SetXColumnName("L")
            series.SetYColumnName(name)
            series.SetPlotType(series.PlotTypeScatter)

    # -- 5. verify -----------------------------------------------------------------------------------------
    def tip_to_surface_mm(self, ipc_node, probe_to_reference, probe_tip_to_probe, reference_to_image):
        """Distance (mm) from the tracked tip, mapped into the image, to the closest IPC point."""
        tip = self.tip_in_reference(probe_to_reference, probe_tip_to_probe)
        tip_image = apply_transform(matrix_of(reference_to_image, "ReferenceToImage"), tip[None])
        return float(self._index(ipc_node, points_of(ipc_node, "IPC model")).nearest(tip_image)[0][0])

    # -- 6. robot ------------------------------------------------------------------------------------------
    def robot_calibration(self, points_robot, points_tracker, reference_to_tracker, reference_to_image):
        """Eqs. 3-4: writes and returns the ``RobotBaseToTracker`` and ``ImageToRobotBase`` transform nodes."""
        base_to_tracker = robot_base_to_tracker(points_robot, points_tracker)
        image_to_base = image_to_robot_base(
            base_to_tracker,
            matrix_of(reference_to_tracker, "ReferenceToTracker"),
            matrix_of(reference_to_image, "ReferenceToImage"),
        )
        parameters = self.parameters
        base_node = parameters.robotBaseToTracker or self.transform_node("RobotBaseToTracker")
        image_node = parameters.imageToRobotBase or self.transform_node("ImageToRobotBase")
        set_matrix(base_node, base_to_tracker)
        set_matrix(image_node, image_to_base)
        parameters.robotBaseToTracker, parameters.imageToRobotBase = base_node, image_node
        return base_node, image_node

    # -- 7. save and reload --------------------------------------------------------------------------------
    def save(self, path):
        """Save the scene with every node's data; returns the files written (the scene first).

        ``.mrb``: one Medical Reality Bundle, written by ``vtkMRMLScene::WriteToMRB``, the function Slicer's own
        scene writer calls for .mrb (qSlicerSceneWriter::writeToMRB, Slicer 5.6 to 5.10). ``.mrml``: the scene file
        with each node's data file beside it. (Slicer's writer for .mrml only commits the XML, so markups, models,
        segmentations and tables would be lost; that is why the Slicer module saves through here.)
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".mrb", ".mrml"):
            raise ValueError(
                f"{path}: give a file name ending in .mrb (one file) or .mrml (the scene and its data files beside it)"
            )
        if path.is_dir():
            raise ValueError(f"{path} is a folder; give a file name ending in {suffix}")
        path.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".mrb":
            if not self.scene.WriteToMRB(str(path)):
                raise RuntimeError(f"writing the scene bundle {path} failed; check that the folder is writable")
            return [path]
        written = []
        for node in _storable_nodes(self.scene):
            if node.GetHideFromEditors() or not _has_data(node):
                continue
            if node.GetStorageNode() is None and not node.AddDefaultStorageNode():
                raise RuntimeError(f"cannot save {node.GetName()!r}: no storage for {node.GetClassName()}")
            storage = node.GetStorageNode()
            extension = storage.GetDefaultWriteFileExtension()
            file_name = path.parent / f"{_safe(node.GetName())}-{_safe(node.GetID())}.{extension}"
            storage.SetFileName(str(file_name))
            if not storage.WriteData(node):
                raise RuntimeError(f"writing {node.GetName()!r} to {file_name} failed")
            written.append(file_name)
        self.scene.SetRootDirectory(str(path.parent))
        self.scene.SetURL(str(path))
        if not self.scene.Commit():
            raise RuntimeError(f"writing the scene file {path} failed")
        return [path, *written]


def load_scene(scene, path):
    """Read a scene saved by ``NavigationLogic.save`` (or by Slicer) into ``scene``, data included: a ``.mrb`` by
    ``vtkMRMLScene::ReadFromMRB`` as Slicer reads it, a ``.mrml`` with its data files."""
    path = Path(path)
    if path.suffix.lower() == ".mrb":
        _give_a_cache_directory(scene)
        if not scene.ReadFromMRB(str(path)):
            raise RuntimeError(f"{path}: cannot read the scene bundle")
        return scene
    scene.SetURL(str(path))
    if not scene.Import():
        raise RuntimeError(f"{path}: cannot read the scene")
    for node in _storable_nodes(scene):
        storage = node.GetStorageNode()
        if storage is not None and storage.GetFileName() and not storage.ReadData(node):
            raise RuntimeError(f"{path}: cannot read the data of {node.GetName()!r} from {storage.GetFileName()}")
    return scene


def _give_a_cache_directory(scene):
    """ReadFromMRB unpacks into the remote cache directory of the scene's data IO manager, which Slicer's
    application sets up; a bare scene (slicer-core) gets one in a new temporary folder."""
    manager = scene.GetDataIOManager()
    cache = None if manager is None else manager.GetCacheManager()
    if cache is not None and cache.GetRemoteCacheDirectory():
        return
    import tempfile

    import slicer

    manager = manager or slicer.vtkDataIOManager()
    cache = cache or slicer.vtkCacheManager()
    cache.SetRemoteCacheDirectory(tempfile.mkdtemp(prefix="ramsicp-mrb-"))
    manager.SetCacheManager(cache)
    scene.SetDataIOManager(manager)
    scene.SetCacheManager(cache)


def _paired_markers(markers_image_node, markers_patient_node):
    """Image and patient marker centres paired as ``ramsicp register`` pairs them (``pair_marker_sets``): by their
    ``M<n>`` labels when the image side numbers its markers (so a deleted marker leaves the others paired right),
    else row by row, checked by the markers' distances (another order is re-paired and said). Markers flagged
    partial or deformed in the CT are refused: their centres may be off. Returns (image (K, 3), patient (K, 3),
    warnings)."""
    sets = []
    for node, name in (
        (markers_image_node, "marker centres (image)"),
        (markers_patient_node, "marker centres (patient)"),
    ):
        points = points_of(node, name)
        labels = [node.GetNthControlPointLabel(i) for i in range(len(points))] if node.IsA("vtkMRMLMarkupsNode") else []
        sets.append(labelled_markers(points, labels or [""] * len(points), node.GetName()))
    image, patient = sets
    if min(len(image.points), len(patient.points)) < 3:
        raise ValueError(
            "the coarse registration needs at least 3 marker centres in both the image and the "
            "patient; detect or place the missing ones"
        )
    if image.flagged():
        raise ValueError(
            f"{flagged_message(image)} in the CT, so its centre may be off: drag it onto the sphere's centre and "
            "rename it 'M<n> ok', or delete it (three markers are enough)"
        )
    pairing = pair_marker_sets(image, patient)
    return pairing.image, pairing.patient, tuple(pairing.warnings)


def _storable_nodes(scene):
    """The scene's storable nodes (by index: ``GetNodesByClass`` returns a collection the caller must release)."""
    count = scene.GetNumberOfNodesByClass("vtkMRMLStorableNode")
    return [scene.GetNthNodeByClass(index, "vtkMRMLStorableNode") for index in range(count)]


def _has_data(node):
    if node.IsA("vtkMRMLTransformNode"):
        return True
    if node.IsA("vtkMRMLMarkupsNode"):
        return True
    if node.IsA("vtkMRMLModelNode"):
        return node.GetPolyData() is not None
    if node.IsA("vtkMRMLTableNode"):
        return node.GetTable() is not None
    if node.IsA("vtkMRMLVolumeNode"):
        return node.GetImageData() is not None
    if node.IsA("vtkMRMLSegmentationNode"):
        return node.GetSegmentation() is not None and node.GetSegmentation().GetNumberOfSegments() > 0
    return False


def _safe(text):
    return "".join(character if character.isalnum() else "_" for character in text)
