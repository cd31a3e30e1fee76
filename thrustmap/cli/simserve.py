"""CLI: ``thrustmap sim-serve flightstand``: a simulated device server for scripts and drivers."""

from __future__ import annotations

import click


@click.command("sim-serve")
@click.argument("device", type=click.Choice(["flightstand"]))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to listen on (loopback unless you name another).",
)
@click.option("--port", type=click.IntRange(0, 65535), default=50051, show_default=True)
@click.option("--plant", default="xnova-2207-6s", show_default=True, help="Simulator preset.")
@click.option("--seed", type=int, default=1, show_default=True, help="Simulator seed (noise).")
@click.option("--no-noise", is_flag=True, help="Noise-free sensors.")
@click.option(
    "--rate", type=float, default=100.0, show_default=True, help="Sample rate of the core, Hz."
)
@click.option(
    "--boards",
    type=click.IntRange(0, 8),
    default=1,
    show_default=True,
    help="Simulated boards connected at start.",
)
@click.option(
    "--no-client-timeout",
    type=click.FloatRange(0.1, 60.0),
    default=1.0,
    show_default=True,
    help="Heartbeat gap (s) after which an active output is cut off.",
)
@click.option("--duration", type=click.FloatRange(min=0.0), help="Stop after this many seconds.")
def simserve_cmd(
    device: str,
    host: str,
    port: int,
    plant: str,
    seed: int,
    no_noise: bool,
    rate: float,
    boards: int,
    no_client_timeout: float,
    duration: float | None,
) -> None:
    """Serve a simulated device until Ctrl-C.

    flightstand: a Tyto Flight Stand core (the official `flightstand` package's gRPC service)
    with thrustmap's motor, propeller and battery simulator behind each board's ESC output. The
    official example scripts and `thrustmap probe/sweep --stand flightstand://HOST:PORT` talk
    to it as to the real core. Needs `pip install 'thrustmap[flightstand]'`."""
    from thrustmap.rig.sim.flightstand_service import FlightStandServer, serve

    def ready(server: FlightStandServer) -> None:
        click.echo(
            f"simulated Flight Stand core on {server.address} "
            f"({boards} board(s), {rate:g} Hz, plant {plant}, seed {seed}); Ctrl-C stops it",
            err=True,
        )

    serve(
        host=host,
        port=port,
        ready=ready,
        duration_s=duration,
        plant=plant,
        seed=seed,
        noise=not no_noise,
        rate_hz=rate,
        boards=boards,
        no_client_timeout_s=no_client_timeout,
    )
