"""Layer 6, experiments: the demo, one registration trial, and the paper's Figs. 7-10 with their report.
Imports the layers below it; only ``cli`` sits above."""
