"""Follow the tracks of a running bintrack network with the client API.

Run:  python examples/latest_tracks.py [-e tcp/127.0.0.1:7447] [--net NAME] [--scans N]

It prints the latest scan the base station holds (its ``tracks`` queryable), then the next N
scans as they are published (positions in the deployment's units, event time in s). Without
--net it takes the one network alive on the bus.
"""

import argparse
import asyncio

from bintrack.client import BintrackClient


async def main(connect: list[str], net: str | None, scans: int) -> None:
    async with BintrackClient(net=net, connect=connect) as client:
        latest = await client.latest_tracks()
        if latest is not None:
            print(f"latest: t={latest.t:.3f}", [(k.track, round(k.x, 2), round(k.y, 2)) for k in latest.tracks])
        seen = 0
        async for track_set in client.tracks():
            print(f"t={track_set.t:.3f}", [(k.track, round(k.x, 2), round(k.y, 2)) for k in track_set.tracks])
            seen += 1
            if seen == scans:
                break


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Follow the tracks of a running bintrack network.")
    parser.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh router, repeatable (default: tcp/127.0.0.1:7447)")
    parser.add_argument("--net", help="network name (default: the one alive on the bus)")
    parser.add_argument("--scans", type=int, default=5, help="scans to print before exiting (default: 5)")
    args = parser.parse_args()
    try:
        asyncio.run(main(args.connect or ["tcp/127.0.0.1:7447"], args.net, args.scans))
    except (ConnectionError, ValueError) as exc:   # no router; no network, or several, alive
        raise SystemExit(f"latest_tracks: {exc}") from None
