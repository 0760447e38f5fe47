"""Qt-free tracker feed of RAMSICP Navigator: NDI tracker -> OpenIGTLink (PLUS names) -> Slicer transform nodes.

In place so far: the two wire formats, each with its CRC checked both ways and malformed input refused with
a reason: ``igtl_messages`` (OpenIGTLink header versions 1 and 2, TRANSFORM, STATUS, metadata) and
``ndi_protocol`` (NDI Combined API framing, ERROR meanings, the TX reply). The NDI driver, the Vega simulator,
the PLUS-compatible server and the Slicer receiver build on them. Recorded tracking: ``plus_sequence`` (PLUS
sequence files, read and written), ``replay`` (a recording through the server), ``recorded_touches`` (the
touches in a recording) and the receiver's ``start_recording``. The frame arithmetic of paper eq. 2,
``ProbeToReference = inv(ReferenceToTracker) @ ProbeToTracker``, is
``RAMSICPRegistrationLib.core.transforms.probe_to_reference``.
"""
