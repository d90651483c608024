"""Subcommands of `scene-recon`; each module has `add_parser(subparsers)` and sets `func`."""

from scene_recon.commands import (
    benchmark_cmd,
    demo_cmd,
    eval_graph_cmd,
    eval_map_cmd,
    eval_scene_cmd,
    generate_cmd,
    graph_cmd,
    inspect_cmd,
    map_cmd,
    replace_cmd,
    ros_run_cmd,
    run_cmd,
    suite_cmd,
)

#: In pipeline order: what `--help` lists.
COMMANDS = [demo_cmd, generate_cmd, suite_cmd, inspect_cmd, map_cmd, eval_map_cmd, graph_cmd, eval_graph_cmd,
            replace_cmd, eval_scene_cmd, run_cmd, ros_run_cmd, benchmark_cmd]
