"""CT volumes: NRRD (pynrrd), NIfTI (nibabel) and Slicer scalar volume nodes, converted once to RAS.

A ``CTVolume`` holds the voxel array indexed ``[i, j, k]`` and the (4, 4) ``ijk_to_ras`` matrix that maps a voxel
index (voxel centres at integer indices) to RAS millimetres, so spacing, origin and direction travel together.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.atomic_files import atomic_path
from ..io.file_checks import PointFileError, check_input_file

_LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])
VOLUME_SUFFIXES = (".nrrd", ".nhdr", ".nii", ".nii.gz")


@dataclass(frozen=True)
class CTVolume:
    """A CT volume: ``voxels`` (I, J, K) in Hounsfield units and ``ijk_to_ras`` (4, 4), mm."""

    voxels: np.ndarray
    ijk_to_ras: np.ndarray

    @property
    def spacing(self):
        """Voxel size along i, j, k (mm), (3,)."""
        return np.linalg.norm(self.ijk_to_ras[:3, :3], axis=0)

    @property
    def direction(self):
        """Unit RAS directions of the i, j, k axes as columns, (3, 3)."""
        return self.ijk_to_ras[:3, :3] / self.spacing

    def ijk_to_ras_points(self, ijk):
        """Map (N, 3) voxel indices (may be fractional) to RAS mm."""
        # einsum, not matmul: an (N, 3) x (3, 3) product gains nothing from BLAS, whose threads only contend.
        return (
            np.einsum("ij,kj->ik", np.asarray(ijk, dtype=np.float64), self.ijk_to_ras[:3, :3]) + self.ijk_to_ras[:3, 3]
        )

    def ras_to_ijk_points(self, ras):
        """Map (N, 3) RAS points (mm) to fractional voxel indices."""
        offsets = np.asarray(ras, dtype=np.float64) - self.ijk_to_ras[:3, 3]
        return np.einsum("ij,kj->ik", offsets, np.linalg.inv(self.ijk_to_ras[:3, :3]))

    def voxels_within(self, low_ras, high_ras):
        """The voxels whose centres may lie in an RAS box (3,) to (3,) mm, which the grid may cut at a slant.

        Returns:
            (box, ras): the index box (3 slices) around them, and the RAS centres (I, J, K, 3) of its voxels;
            (None, None) when the box lies outside the volume.
        """
        corners = np.array(
            [
                [x, y, z]
                for x in (low_ras[0], high_ras[0])
                for y in (low_ras[1], high_ras[1])
                for z in (low_ras[2], high_ras[2])
            ]
        )
        ijk = self.ras_to_ijk_points(corners)
        low = np.maximum(np.floor(ijk.min(axis=0)).astype(int), 0)
        high = np.minimum(np.ceil(ijk.max(axis=0)).astype(int), np.array(self.voxels.shape) - 1)
        if (high < low).any():
            return None, None
        box = tuple(slice(a, b + 1) for a, b in zip(low, high))
        grid = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(low, high)], indexing="ij"), axis=-1)
        return box, self.ijk_to_ras_points(grid.reshape(-1, 3)).reshape(grid.shape)


def check_volume(voxels, ijk_to_ras, name="CT volume"):
    """Validate a volume; returns a CTVolume. Raises ValueError saying what to change."""
    voxels = np.asarray(voxels)
    if voxels.ndim != 3:
        raise ValueError(
            f"{name}: expected a 3-D volume, got {voxels.ndim} dimension(s) of shape {voxels.shape}; "
            "load a CT series, not a single slice or a time series"
        )
    if min(voxels.shape) < 2:
        raise ValueError(
            f"{name}: shape {voxels.shape} is empty or flat; the CT needs at least 2 voxels along each axis"
        )
    ijk_to_ras = np.asarray(ijk_to_ras, dtype=np.float64)
    if ijk_to_ras.shape != (4, 4) or not np.isfinite(ijk_to_ras).all():
        raise ValueError(f"{name}: the voxel-to-RAS matrix must be a finite 4x4 matrix")
    spacing = np.linalg.norm(ijk_to_ras[:3, :3], axis=0)
    if (spacing <= 1e-6).any() or abs(np.linalg.det(ijk_to_ras[:3, :3])) <= 1e-12:
        raise ValueError(
            f"{name}: voxel spacing {np.round(spacing, 6).tolist()} mm has a zero; "
            "fix the spacing in the file header (e.g. 0.5 0.5 0.625)"
        )
    return CTVolume(voxels=voxels, ijk_to_ras=ijk_to_ras)


def load_volume(source):
    """Load a CT volume from a ``.nrrd``/``.nhdr``/``.nii``/``.nii.gz`` file, a DICOM series folder, or a Slicer
    scalar volume node.

    Raises:
        PointFileError: a file that is missing, empty, of unknown type or unreadable (names the file and the problem).
        ValueError: a volume that is not 3-D, is empty, or has a zero spacing.
    """
    if hasattr(source, "IsA"):  # a VTK object: it must be a scalar volume node
        return volume_from_node(source)
    path = Path(source)
    if path.is_dir():
        voxels, ijk_to_ras = _read_dicom_series(path)
        return check_volume(voxels, ijk_to_ras, name=str(path))
    check_input_file(path, "CT volume")
    name = path.name.lower()
    try:
        if name.endswith((".nrrd", ".nhdr")):
            voxels, ijk_to_ras = _read_nrrd(path)
        elif name.endswith((".nii", ".nii.gz")):
            voxels, ijk_to_ras = _read_nifti(path)
        else:
            raise PointFileError(path, f"unknown volume type; use one of {', '.join(VOLUME_SUFFIXES)}")
    except PointFileError:
        raise
    except Exception as error:  # the readers raise many types for a damaged file
        detail = " ".join(str(error).split()) or "it ends early or is damaged"
        raise PointFileError(path, f"cannot read as a volume ({detail}); export the CT again") from None
    try:
        return check_volume(voxels, ijk_to_ras, name=str(path))
    except ValueError as error:
        raise PointFileError(path, str(error).split(": ", 1)[1]) from None


def volume_from_node(node):
    """CTVolume from a Slicer ``vtkMRMLScalarVolumeNode`` (real MRML; its voxels are copied), in world RAS.

    The geometry is where Slicer shows the volume: its IJK-to-RAS matrix, with the linear transform it sits under
    applied (``GetMatrixTransformToWorld`` of its parent transform node). A volume under a non-linear transform
    is refused: its voxels no longer lie on a grid that one matrix describes.
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    if not (hasattr(node, "IsA") and node.IsA("vtkMRMLScalarVolumeNode")):
        raise TypeError(f"expected a vtkMRMLScalarVolumeNode, got {type(node).__name__}")
    image = node.GetImageData()
    if image is None:
        raise ValueError(f"volume node {node.GetName()!r} has no image data; load the CT first")
    dimensions = image.GetDimensions()
    voxels = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(dimensions[::-1]).transpose(2, 1, 0).copy()
    matrix = vtkMatrix4x4()
    node.GetIJKToRASMatrix(matrix)
    ijk_to_ras = _array(matrix)
    parent = node.GetParentTransformNode()
    if parent is not None:
        if not parent.IsTransformToWorldLinear():
            raise ValueError(
                f"volume node {node.GetName()!r} is under the non-linear transform {parent.GetName()!r}; harden "
                "the transform on the CT (Data module: right-click the CT, 'Harden transform') or take the CT out "
                "of it, so that one matrix places its voxels"
            )
        parent.GetMatrixTransformToWorld(matrix)
        ijk_to_ras = _array(matrix) @ ijk_to_ras
    return check_volume(voxels, ijk_to_ras, name=f"volume node {node.GetName()!r}")


def _array(matrix):
    """A vtkMatrix4x4 as a (4, 4) array."""
    return np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])


def save_nrrd(path, volume):
    """Write a CTVolume as NRRD in LPS (as Slicer writes), gzip-compressed; float HU become int16, labels stay."""
    import nrrd

    ijk_to_lps = _LPS_TO_RAS @ volume.ijk_to_ras
    voxels = volume.voxels
    if np.issubdtype(voxels.dtype, np.floating) and np.all(np.abs(voxels) < 32000):
        voxels = np.round(voxels).astype(np.int16)
    header = {
        "space": "left-posterior-superior",
        "space directions": ijk_to_lps[:3, :3].T,
        "space origin": ijk_to_lps[:3, 3],
        "kinds": ["domain", "domain", "domain"],
        "encoding": "gzip",
    }
    with atomic_path(path) as temporary:  # whole or not at all
        nrrd.write(str(temporary), voxels, header, index_order="F")


def _read_nrrd(path):
    import nrrd

    voxels, header = nrrd.read(str(path), index_order="F")
    directions = header.get("space directions")
    if directions is None:
        raise PointFileError(path, "the NRRD header has no 'space directions'; it does not say where the voxels are")
    directions = np.array([row for row in directions if row is not None and np.all(np.isfinite(row))], float)
    if voxels.ndim != 3 or directions.shape != (3, 3):
        raise PointFileError(path, f"expected a 3-D volume with 3 space directions, got shape {voxels.shape}")
    origin = np.asarray(header.get("space origin", np.zeros(3)), dtype=np.float64)
    matrix = np.eye(4)
    matrix[:3, :3] = directions.T  # each row of 'space directions' is the step of one voxel axis
    matrix[:3, 3] = origin
    space = str(header.get("space", "left-posterior-superior")).lower()
    if space in ("left-posterior-superior", "lps"):
        matrix = _LPS_TO_RAS @ matrix
    elif space not in ("right-anterior-superior", "ras"):
        raise PointFileError(path, f"NRRD space {space!r} is not LPS or RAS")
    return voxels, matrix


def _read_nifti(path):
    import nibabel

    image = nibabel.load(str(path))
    voxels = np.asanyarray(image.dataobj)
    if voxels.ndim == 4 and voxels.shape[3] == 1:
        voxels = voxels[..., 0]
    return voxels, np.asarray(image.affine, dtype=np.float64)  # NIfTI's affine maps voxels to RAS+


def _read_dicom_series(folder):
    """Read the CT series in a folder with pydicom: slices sorted along their normal, HU via the rescale tags."""
    import pydicom
    from pydicom.errors import InvalidDicomError

    headers = []
    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        try:
            header = pydicom.dcmread(str(path), stop_before_pixels=True)
        except (InvalidDicomError, OSError):
            continue  # not a DICOM file: DICOMDIR companions, notes
        if "ImagePositionPatient" in header and "ImageOrientationPatient" in header:
            headers.append((path, header))
    if not headers:
        raise PointFileError(
            folder,
            "no DICOM image with a position and orientation in this folder; give a CT file "
            f"({', '.join(VOLUME_SUFFIXES)}) or a folder holding one DICOM series",
        )
    series = {}
    for path, header in headers:
        series.setdefault(str(header.get("SeriesInstanceUID", "")), []).append((path, header))
    if len(series) > 1:
        sizes = ", ".join(f"{uid or '(none)'}: {len(items)} slices" for uid, items in series.items())
        raise PointFileError(folder, f"holds {len(series)} DICOM series ({sizes}); put one series in a folder")
    slices = next(iter(series.values()))
    orientation = np.array(slices[0][1].ImageOrientationPatient, dtype=np.float64)
    along_row, along_column = orientation[:3], orientation[3:]
    normal = np.cross(along_row, along_column)
    slices.sort(key=lambda item: float(np.dot(np.array(item[1].ImagePositionPatient, dtype=np.float64), normal)))
    positions = np.array([item[1].ImagePositionPatient for item in slices], dtype=np.float64)
    if len(slices) < 2:
        raise PointFileError(folder, "a single DICOM slice is not a volume; export the whole series")
    steps = np.diff(positions, axis=0)
    if np.linalg.norm(steps, axis=1).min() < 1e-6:
        raise PointFileError(folder, "two slices share one position; the series holds duplicates")
    row_spacing, column_spacing = (float(v) for v in slices[0][1].PixelSpacing)
    images = []
    for path, _ in slices:
        dataset = pydicom.dcmread(str(path))
        slope = float(getattr(dataset, "RescaleSlope", 1.0))
        intercept = float(getattr(dataset, "RescaleIntercept", 0.0))
        images.append(dataset.pixel_array.T.astype(np.float32) * slope + intercept)  # (columns, rows) = (i, j)
    ijk_to_lps = np.eye(4)
    ijk_to_lps[:3, 0] = along_row * column_spacing
    ijk_to_lps[:3, 1] = along_column * row_spacing
    ijk_to_lps[:3, 2] = (positions[-1] - positions[0]) / (len(slices) - 1)
    ijk_to_lps[:3, 3] = positions[0]
    voxels = np.stack(images, axis=-1)
    if np.all(voxels == np.round(voxels)) and np.abs(voxels).max() < 32768:
        voxels = voxels.astype(np.int16)
    return voxels, _LPS_TO_RAS @ ijk_to_lps
