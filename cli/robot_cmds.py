"""`accrue robot learner`: the learner process of a hardware stage on another host (the GPU box).

The actor (`accrue stage run` beside the robot, with `robot.learner_address: HOST:PORT`) sends it what it
needs and every sealed episode; this process holds nothing durable and may be restarted at any time.
"""

from __future__ import annotations

from typing import Annotated

import typer

robot_app = typer.Typer(help="Robot sessions: the learner process for a second host.", no_args_is_help=True)


@robot_app.command("learner")
def learner(
    listen: Annotated[str, typer.Option("--listen", help="HOST:PORT to serve the actor on.")] = "0.0.0.0:50051",
) -> None:
    """Serve an actor's learner over gRPC until interrupted (insecure channel: a trusted LAN only)."""
    from accrue.robot.learner_service import main

    raise typer.Exit(main(["--listen", listen]))


def register(app: typer.Typer) -> None:
    app.add_typer(robot_app, name="robot")
