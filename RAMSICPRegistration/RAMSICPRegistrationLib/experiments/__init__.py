"""Layer 6, experiments: the demo, one registration trial, and the paper's Figs. 7-10 with their report.
Imports the layers below it and the tracker and robot feed (OpenIGTLinkBridgeLib); ``web`` and ``commands``
sit above."""
