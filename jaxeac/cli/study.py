"""`jaxeac study`: every task x AC, EAC, its ablations and the baselines, compared with AC."""

from __future__ import annotations

import argparse

from jaxeac.cli.flags import finite_float, folder_name, positive_int, prng_key
from jaxeac.errors import UsageError


def add_parser(sub) -> None:
    st = sub.add_parser("study", help="every task x AC, EAC, its ablations, Q-learning and SARSA, compared "
                                      "with AC (resumable)")
    st.add_argument("--tasks", nargs="+", metavar="NAME[:slip=P]",
                    help="registered environments (default: the paper grid, plain and with slip 0.1, and "
                         "every classic task)")
    st.add_argument("--algos", nargs="+", metavar="ALGO", help="algorithms, ac among them (default: all)")
    st.add_argument("--seeds", type=positive_int, default=10_000, metavar="N",
                    help="seeds per algorithm and task")
    st.add_argument("--trials", type=positive_int, metavar="T",
                    help="trials per run (default: the preset's 200)")
    st.add_argument("--epsilon", type=finite_float, default=0.1, metavar="E",
                    help="ε of q_learning and sarsa")
    st.add_argument("--resamples", type=positive_int, default=10_000, metavar="R", help="bootstrap resamples")
    st.add_argument("--key", type=prng_key, default=0, metavar="K", help="root PRNG key, 0..2^32-1 (SPEC R1)")
    st.add_argument("--chunk-size", type=positive_int, default=None, metavar="M",
                    help="seeds per compiled batch (default: automatic; results do not depend on it)")
    st.add_argument("--lanes", type=positive_int, default=None, metavar="L",
                    help="seeds in flight per device (default: automatic; results do not depend on it)")
    st.add_argument("--tune", action="append", metavar="[ALGO.]KEY=V1,V2,...",
                    help="tune: a grid of values of alpha, beta, gamma, temperature or epsilon, each algorithm over "
                         "the keys it reads (ALGO.KEY: that algorithm only); repeat for several keys. Every algorithm "
                         "is then also evaluated at its best setting per task and across tasks")
    st.add_argument("--tune-seeds", type=positive_int, default=None, metavar="N",
                    help="tuning seeds per setting, algorithm and task (default with --tune: 200)")
    st.add_argument("--tune-key", type=prng_key, default=None, metavar="K",
                    help="root PRNG key of the tuning seeds; must differ from --key (default: --key + 1)")
    st.add_argument("--out", type=folder_name, default="runs/study", metavar="DIR",
                    help="study folder (default runs/study)")
    st.add_argument("--quiet", action="store_true", help="no progress lines")
    st.add_argument("--timeline", action="store_true",
                    help="print where the time went, per task and phase (study.json's timeline keeps it)")


def cmd_study(args: argparse.Namespace) -> int:
    from jaxeac.cli.process import _claim_out, _ended_with_command
    from jaxeac.experiments.common import check_grid_resources
    from jaxeac.experiments.study import (
        DEFAULT_ALGOS,
        DEFAULT_TASKS,
        StudySettings,
        run_study,
        study_tasks,
        summary_table,
        task_envs,
    )
    from jaxeac.experiments.study_runs import diagnostics_helper

    settings = StudySettings(
        tasks=tuple(args.tasks or DEFAULT_TASKS), algos=tuple(args.algos or DEFAULT_ALGOS), seeds=args.seeds,
        trials=args.trials, key=args.key, epsilon=args.epsilon, resamples=args.resamples,
        chunk_size=args.chunk_size, lanes=args.lanes)
    settings.validate()  # bad names and settings fail before any compute
    tuning = None
    if args.tune or args.tune_seeds is not None or args.tune_key is not None:
        from jaxeac.experiments.tune import Tuning

        if not args.tune:
            raise UsageError("--tune-seeds and --tune-key need a grid: give at least one --tune KEY=V1,V2,...")
        tuning = Tuning.build(args.tune, algos=settings.algos, seeds=args.tune_seeds or 200, key=args.tune_key,
                              eval_key=settings.key, trials=settings.task_settings(settings.tasks[0]).trials,
                              out=args.out)  # a folder tuned with another setup is refused here
    grids = {task: settings.task_settings(task) for task in settings.tasks}
    envs = task_envs(grids)  # the runs' own environments: tasks of one layout share their kernel probes
    _, todo = study_tasks(settings, args.out, grids, envs)
    helper = _ended_with_command(args, diagnostics_helper(todo))  # E8 (GPUs) starts while the checks run
    for task, grid in grids.items():  # sizes that cannot fit or finish fail here, for every task
        check_grid_resources(grid, envs[task])
    _claim_out(args, args.out, kind="study")
    result = run_study(settings, args.out, progress=not args.quiet, tuning=tuning, timeline=args.timeline,
                       helper=helper)
    print(summary_table(result))
    if tuning is not None:
        from jaxeac.experiments.tune import tuned_summary

        print(tuned_summary(result["tuning"]))
    if args.timeline:
        from jaxeac.experiments.study import timeline_text

        print(timeline_text(result["timeline"]))
    print(f"{len(settings.tasks)} tasks x {len(settings.algos)} algorithms x {settings.seeds:,} seeds; "
          f"{result['comparisons_in_family']} comparisons with ac; report in {args.out}/report.md")
    return 0
