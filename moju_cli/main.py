"""``moju``: command-line entry point.

Solver commands (``reconstruct``, ``evaluate``, ``demo``) live in
:mod:`moju_cli.solver_commands`; service commands (``serve``, ``worker``, ``submit``) live in
:mod:`moju_cli.service_commands` and import the service packages only when they run;
``view`` (the result viewer as a standalone HTML file) lives in :mod:`moju_cli.view_commands`;
``track`` (dense 2D tracks from a video) lives in :mod:`moju_cli.video_commands`.
"""

from __future__ import annotations

import click

from moju_core import __version__


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="moju")
def cli() -> None:
    """Dense non-rigid structure from motion (MoJu, CVPR 2019)."""


def _register() -> None:
    from moju_cli import service_commands, solver_commands, video_commands, view_commands

    for module in (solver_commands, service_commands, view_commands, video_commands):
        for command in module.COMMANDS:
            cli.add_command(command)


_register()
