"""The `swarmctl` command. Each sub-command is a thin layer over the packages."""

from __future__ import annotations

import sys

import click

from swarmctl.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, InputError, printable


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="swarmctl")
def cli() -> None:
    """Drone-swarm search: simulate, train, plan over real areas, fly over MAVLink."""


from swarmctl.bench import bench_command  # noqa: E402
from swarmctl.geo.cli import plan_command  # noqa: E402
from swarmctl.learn.cli import eval_command, train_command, train_search_command  # noqa: E402
from swarmctl.mission.cli import agent_command, demo_command, fly_command  # noqa: E402
from swarmctl.replay.cli import replay_command  # noqa: E402
from swarmctl.sim.cli import mock_relay_command, mock_vehicle_command  # noqa: E402

for command in (
    eval_command,
    train_command,
    train_search_command,
    bench_command,
    plan_command,
    mock_vehicle_command,
    mock_relay_command,
    demo_command,
    fly_command,
    agent_command,
    replay_command,
):
    cli.add_command(command)


def one_line(message: str) -> str:
    """A message as the single line the CLI prints (what is not printable in it escaped)."""
    return printable(" ".join(message.split()))


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning bad input into one line on stderr and exit status 2."""
    try:
        result = cli.main(args=argv, prog_name="swarmctl", standalone_mode=False)
    except InputError as exc:
        click.echo(f"swarmctl: error: {one_line(str(exc))}", err=True)
        return EXIT_BAD_INPUT
    except OSError as exc:  # a file no check foresaw could not be read or written: a full disk, a name too long
        where = f"{exc.filename}: " if exc.filename else ""
        text = one_line(f"{where}{exc.strerror or exc}")
        click.echo(f"swarmctl: error: {text}; check the path, its permissions and the free space", err=True)
        return EXIT_BAD_INPUT
    except click.exceptions.NoArgsIsHelpError as exc:  # `swarmctl` alone: the help
        exc.show()
        return exc.exit_code
    except click.UsageError as exc:  # a bad option or argument: click's message, the help to read
        where = exc.ctx.command_path if exc.ctx is not None else "swarmctl"
        click.echo(f"swarmctl: error: {one_line(exc.format_message()).rstrip('.')}; see '{where} --help'", err=True)
        return EXIT_BAD_INPUT
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("swarmctl: interrupted", err=True)
        return EXIT_INTERRUPTED
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.ClickException as exc:
        click.echo(f"swarmctl: error: {one_line(exc.format_message())}", err=True)
        return exc.exit_code
    # without standalone mode click hands back a command's exit status (click.exceptions.Exit) here
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
