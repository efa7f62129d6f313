"""Ray, the distributed engine of ``uavdata simulate`` (a corpus) and ``uavrl sweep``: started or joined here, with
the two checks that keep a command from waiting forever without a word: an address nothing answers, and tasks that
ask for more CPUs than the cluster has."""

from __future__ import annotations

import os
import socket

from uavplace.schemas.base import InputError

#: Seconds to wait for a Ray head at ``--ray-address`` to answer before refusing it.
CONNECT_TIMEOUT_S = 10.0


def head_endpoint(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a ``HOST:PORT`` or ``ray://HOST:PORT`` address; None for ``auto`` (Ray finds its own);
    ``InputError`` on the ``--ray-address`` field for anything else."""
    if address == "auto":
        return None
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(None, f"{address!r}: expected HOST:PORT, ray://HOST:PORT or auto", field="--ray-address")
    return host.strip("[]"), int(port)


#: An HTTP/2 client's first bytes, then an empty SETTINGS frame: a gRPC server (a Ray head, a Ray Client server)
#: answers with its own SETTINGS frame; anything else (a web server, a listener that never answers) does not.
_HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def check_ray_head(address: str, endpoint: tuple[str, int]) -> None:
    """Refuse (``InputError`` on ``--ray-address``) an address where nothing answers within ``CONNECT_TIMEOUT_S``,
    or where what answers does not speak gRPC as a Ray head does (Ray would retry it for ever)."""
    try:
        conn = socket.create_connection(endpoint, timeout=CONNECT_TIMEOUT_S)
    except OSError as err:
        reason = "no answer" if isinstance(err, TimeoutError) else (err.strerror or type(err).__name__)
        raise InputError(
            None, f"{address}: nothing answers there ({reason} within {CONNECT_TIMEOUT_S:g} s)", field="--ray-address"
        ) from None
    head = b""
    with conn:
        try:
            conn.sendall(_HTTP2_HELLO)
            while len(head) < 9 and (chunk := conn.recv(9 - len(head))):
                head += chunk
        except OSError:  # a timeout, a reset: what answers is not a Ray head
            pass
    if len(head) < 9 or head[3] != 4:  # no SETTINGS frame back
        said = "no answer" if not head else f"an answer that is not gRPC ({head[:9]!r})"
        raise InputError(
            None,
            f"{address}: not a Ray head ({said} within {CONNECT_TIMEOUT_S:g} s): give the head's GCS address, "
            "HOST:6379 by default, or ray://HOST:10001 for Ray Client",
            field="--ray-address",
        )


def ray_driver() -> bool:
    """Whether this process is the driver of a Ray it has joined (``start_ray``: a report's ``--workers`` or
    ``--ray-address``), not one of its tasks; Ray is not imported to ask."""
    import sys

    ray = sys.modules.get("ray")
    return ray is not None and ray.is_initialized() and ray.get_runtime_context().get_task_id() is None


def start_ray(address: str | None, cpus_per_task: float, cpus_option: str, num_cpus: int | None = None) -> bool:
    """Start a local Ray (``address`` None) or join the cluster at ``address``, for tasks of ``cpus_per_task`` CPUs;
    True when this call started it (the caller shuts it down). Refused in one line (``InputError``): an address that
    does not answer within ``CONNECT_TIMEOUT_S``, tasks larger than every CPU the machine or cluster has (they would
    wait forever), and a Ray that does not start (a node that timed out during startup under load), saying what to
    do. ``num_cpus``: the CPUs a local Ray may use (default: every one)."""
    import ray

    if ray.is_initialized():
        return False
    if address is None:
        have = os.cpu_count() or 1
        if num_cpus is not None and num_cpus > have:  # a worker a CPU: more would only share the cores, in memory
            raise InputError(None, f"{num_cpus}: this machine has {have} CPUs: give at most {have}", field=cpus_option)
        if cpus_per_task > have:
            raise InputError(
                None, f"{cpus_per_task:g}: this machine has {have} CPUs: a task would wait for them forever", field=cpus_option
            )
    else:
        endpoint = head_endpoint(address)
        if endpoint is not None:
            check_ray_head(address, endpoint)
    try:
        local = {"num_cpus": num_cpus} if address is None and num_cpus else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False, **local)
    except Exception as err:  # noqa: BLE001 - Ray raises bare Exceptions (a node that timed out during startup)
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
        where = "the local Ray" if address is None else f"the Ray cluster at {address}"
        raise InputError(
            None,
            f"{where} did not start ({first}): run the command again (a busy machine starts Ray "
            "slowly), join a running cluster with --ray-address, or ask for fewer CPUs",
            field=cpus_option if address is None else "--ray-address",
        ) from None
    have = float(ray.cluster_resources().get("CPU", 0))
    if cpus_per_task > have:
        ray.shutdown()
        raise InputError(
            None, f"{cpus_per_task:g}: the Ray cluster has {have:g} CPUs: a task would wait for them forever", field=cpus_option
        )
    return True
