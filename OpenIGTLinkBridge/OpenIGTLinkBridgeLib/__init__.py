"""Qt-free tracker feed of RAMSICP Navigator: NDI driver, simulator, OpenIGTLink server and receiver.

The tracking chain (NDI Combined API -> OpenIGTLink with PLUS names -> Slicer transform nodes) lands here; the
frame arithmetic it relies on (paper eq. 2, ``ProbeToReference = inv(ReferenceToTracker) @ ProbeToTracker``)
is ``RAMSICPRegistrationLib.transforms.probe_to_reference``.
"""
