#!/usr/bin/python3
"""Byte forwarder between a TCP port on loopback and a unix socket.

The demo runs its sessions in a private network namespace (netns-run.sh),
whose loopback a browser on the host cannot reach. Two forwarders join them
through a unix socket in the shared file system, so nothing leaves loopback:

    host:   observer_forward.py --listen tcp  --tcp 127.0.0.1:8080 --unix out/observers.sock
    netns:  observer_forward.py --listen unix --unix out/observers.sock --tcp 127.0.0.1:8080

Each accepted connection is piped both ways to a new connection on the
other side until either end closes. Stops on SIGTERM or SIGINT.
"""
import argparse
import asyncio
import ipaddress
import os
import signal
import sys


async def pipe(reader, writer):
    try:
        while True:
            data = await reader.read(65536)
            if not data:
                break
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        try:
            writer.close()
        except Exception:  # noqa: BLE001 - already closed
            pass


async def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--listen", choices=["tcp", "unix"], required=True, help="which side accepts connections")
    ap.add_argument("--tcp", required=True, help="HOST:PORT on loopback")
    ap.add_argument("--unix", required=True, help="unix socket path")
    args = ap.parse_args()
    host, _, port = args.tcp.rpartition(":")
    if not ipaddress.ip_address(host).is_loopback:
        sys.exit(f"observer_forward: --tcp {args.tcp}: only loopback addresses are forwarded")
    port = int(port)

    async def to_other(reader, writer):
        try:
            if args.listen == "tcp":
                r2, w2 = await asyncio.open_unix_connection(args.unix)
            else:
                r2, w2 = await asyncio.open_connection(host, port)
        except OSError:
            writer.close()
            return
        await asyncio.gather(pipe(reader, w2), pipe(r2, writer))

    if args.listen == "tcp":
        server = await asyncio.start_server(to_other, host, port, reuse_address=True)
    else:
        if os.path.exists(args.unix):
            os.unlink(args.unix)
        server = await asyncio.start_unix_server(to_other, args.unix)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with server:
        await stop.wait()
    if args.listen == "unix" and os.path.exists(args.unix):
        os.unlink(args.unix)


if __name__ == "__main__":
    asyncio.run(main())
