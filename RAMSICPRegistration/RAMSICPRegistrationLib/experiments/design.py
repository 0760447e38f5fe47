"""What the reproduction of the paper's Figs. 7-10 runs: its experiments, its subjects' bones, its repetitions.

Kept apart from ``experiments.py``, which needs the whole image side, so that the command line can show them in its
help without loading it.
"""

#: The paper's figures, then the guided touches (beyond the paper: ``experiments.guided``).
EXPERIMENTS = ("fig7", "fig8", "fig9", "fig10a", "fig10b", "guided")
SUBJECT_BONES = ("right-tibia", "right-ilium", "left-tibia", "right-fibula")
#: Repetitions per condition and bone (the paper's), and per subject for Fig. 8 (4 subjects x 4 = 16 per bone).
DEFAULT_TRIALS = {"fig7": 10, "fig8": 4, "fig9": 5, "fig10a": 10, "fig10b": 10, "guided": 10}
DEFAULT_SUBJECTS = 16
