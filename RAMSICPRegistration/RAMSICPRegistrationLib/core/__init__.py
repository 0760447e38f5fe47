"""Layer 1, the registration core: numpy, scipy and the standard library only (no VTK, no MRML, no Qt).

Paired-point SVD fit (eq. 5), ICP and RAMSICP (eqs. 6-10), the scale sweep, TRE/FRE metrics (eq. 11), the pose
constraint analysis, pivot and robot calibration (eqs. 3-4, the four-point TCP), the osteotomy plan (plane x bone,
the paper's targets), its tool path and the live guidance numbers. Arrays in, arrays and frozen dataclasses out.
"""
