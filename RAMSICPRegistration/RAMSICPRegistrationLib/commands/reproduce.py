"""``ramsicp reproduce``: the paper's experiments (Figs. 7-10) on CT phantoms of four bones, with every method, and
the guided touches (beyond the paper)."""

import time
from pathlib import Path

from ..experiments.design import DEFAULT_SUBJECTS, EXPERIMENTS, SUBJECT_BONES
from ..io.file_checks import check_output_folder
from ._arguments import COUNT, SEED
from ._console import Progress


def add_parser(commands):
    reproduce = commands.add_parser(
        "reproduce",
        help="the paper's experiments (Figs. 7-10) on CT phantoms of four bones, with every method",
        description="Runs the paper's experiments on virtual patients (CT phantoms of the shipped bones with a "
        "reference body): Fig. 7 the TRE against the scale factor L, Fig. 8 the methods compared, Fig. 9 the "
        "robustness to a poor coarse registration, Figs. 10a/10b the number and spread of probe points; beyond the "
        "paper, 'guided' the TRE against the number of touches, touched where the predicted TRE falls most, freely or "
        "in the paper's sub-areas. Writes report.md (only what this run measured), results.json and one figure per "
        "experiment into --out.",
    )
    reproduce.add_argument(
        "--experiment",
        choices=(*EXPERIMENTS, "all"),
        default="all",
        help="which experiment to run (default all: the paper's figures and guided)",
    )
    reproduce.add_argument("--trials", type=COUNT, help="repetitions per condition (default: the paper's)")
    reproduce.add_argument(
        "--subjects",
        type=COUNT,
        default=DEFAULT_SUBJECTS,
        help=f"virtual patients, the bones {', '.join(SUBJECT_BONES)} in turn (default {DEFAULT_SUBJECTS})",
    )
    reproduce.add_argument("--seed", type=SEED, default=0, help="random seed (default 0); a seed repeats a run exactly")
    reproduce.add_argument(
        "--image-source",
        choices=("ct", "mesh"),
        default="ct",
        help="ct: IPC and marker centres from a CT phantom (default); mesh: IPC sampled on the bone mesh",
    )
    reproduce.add_argument(
        "--out", type=Path, default=Path("reproduction"), help="folder for report.md, results.json, PNGs"
    )
    reproduce.set_defaults(run=run)


def run(arguments):
    from ..experiments.experiment_report import write_outputs
    from ..experiments.experiments import run_experiments

    check_output_folder(arguments.out, "--out")
    clock = time.perf_counter()
    experiments = EXPERIMENTS if arguments.experiment == "all" else (arguments.experiment,)
    results = run_experiments(
        experiments,
        trials=arguments.trials,
        seed=arguments.seed,
        subjects=arguments.subjects,
        image_source=arguments.image_source,
        progress=Progress(),
    )
    results["settings"]["seconds"] = time.perf_counter() - clock
    paths = write_outputs(results, arguments.out)
    print(
        f"{len(experiments)} experiment(s) on {arguments.subjects} subject(s) in {results['settings']['seconds']:.0f} s"
    )
    for name, path in paths.items():
        print(f"  {name:<8} {path}")
    return 0
