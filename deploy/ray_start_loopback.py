"""``ray start`` that keeps a loopback ``--node-ip-address`` (deploy/local-cluster.sh runs every node through it).

Ray 2.60 replaces 127.0.0.1 with the machine's routable address wherever it resolves an address, and a node's
servers then listen there. ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` stops that, but ``ray start`` then refuses to join
a node to a cluster. So this reads Ray's constants with the setting on (the join is allowed), keeps the node address
as given, and sets it to 0 for every process the node starts (raylet, agents, workers, job drivers): they resolve
127.0.0.1 to itself and reach the cluster's loopback ports. Then it runs Ray's own ``ray`` command line.
"""

import os

import ray._private.services as services
from ray.scripts.scripts import main

LOOPBACK_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def keep_host(host: str) -> str:
    if not host:
        raise ValueError(f"Malformed host: {host}")
    return host


if __name__ == "__main__":
    services.resolve_ip_for_localhost = keep_host
    os.environ[LOOPBACK_SWITCH] = "0"  # read by the processes the node starts, not by this one (already imported)
    main()
