"""Layer 5, navigation on an MRML scene: the surgeon's workflow logic, MRML node adapters, the workflow scenario
shared by pytest and the Slicer self-test, and offscreen scene rendering. Imports the layers below it."""
