"""``ray start`` that keeps a loopback ``--node-ip-address`` (deploy/local-cluster.sh runs every node through it).

Ray 2.60 replaces 127.0.0.1 with the machine's routable address before it starts a node, and the node's servers
then listen there; ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` keeps the address but refuses to join a node to a
cluster. This shim keeps the address as given and runs Ray's own ``ray`` command line; nothing else changes.
"""

import ray._private.services as services
from ray.scripts.scripts import main


def keep_host(host: str) -> str:
    if not host:
        raise ValueError(f"Malformed host: {host}")
    return host


if __name__ == "__main__":
    services.resolve_ip_for_localhost = keep_host
    main()
