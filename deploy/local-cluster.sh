#!/usr/bin/env bash
# A Ray cluster of one head and N worker nodes on ONE machine, all on 127.0.0.1 with their own ports.
#
#   deploy/local-cluster.sh start N    # head + N workers; prints the dashboard URL for `motionaug submit`
#   deploy/local-cluster.sh stop       # stops ONLY the processes this script started (never `ray stop`)
#   deploy/local-cluster.sh status     # which of them are alive
#
# Every node runs `ray start --block` in its own session (setsid); the session ids go to
# $CLUSTER_DIR/pids and `stop` kills exactly the processes of those sessions (Ray's workers change their
# process group but keep the session). Settings (environment):
#   CLUSTER_DIR     state, logs and Ray's temp dir      (default: ./.local-cluster)
#   RAY_BIN         the ray executable                  (default: ray on PATH)
#   RAY_PYTHON      the Python that runs it              (default: the python beside RAY_BIN)
#   GCS_PORT        head GCS port                        (default: 6390)
#   DASHBOARD_PORT  dashboard / Jobs API port            (default: 8275)
#   AGENT_PORT      first dashboard-agent port; node i uses AGENT_PORT+2i and +2i+1 (default: 52400)
#   CPUS_PER_NODE   --num-cpus of every node             (default: 1)
# Token auth: RAY_AUTH_MODE defaults to token here; a token is generated with `ray get-auth-token --generate`
# when none exists (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token). RAY_AUTH_MODE=disabled turns it off.
set -euo pipefail

CLUSTER_DIR=${CLUSTER_DIR:-$PWD/.local-cluster}
RAY_BIN=${RAY_BIN:-ray}
GCS_PORT=${GCS_PORT:-6390}
DASHBOARD_PORT=${DASHBOARD_PORT:-8275}
AGENT_PORT=${AGENT_PORT:-52400}
CPUS_PER_NODE=${CPUS_PER_NODE:-1}
PIDS="$CLUSTER_DIR/pids"
export RAY_USAGE_STATS_ENABLED=0
export RAY_AUTH_MODE=${RAY_AUTH_MODE:-token}
# Ray 2.60 swaps a loopback --node-ip-address for the machine's routable address, and a node's GCS, raylet, object
# manager and agents then listen there; ray_start_loopback.py runs `ray start` keeping 127.0.0.1, so every port the
# cluster opens is on 127.0.0.1 (tests/test_cluster.py reads the listening sockets back).
RAY_PYTHON=${RAY_PYTHON:-$(dirname "$(command -v "$RAY_BIN")")/python}
LOOPBACK_START="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)/ray_start_loopback.py"

die() { echo "local-cluster: $*" >&2; exit 1; }

ensure_token() {
  [[ "$RAY_AUTH_MODE" == "disabled" ]] && return 0
  [[ -n "${RAY_AUTH_TOKEN:-}" ]] && return 0
  [[ -f "${RAY_AUTH_TOKEN_PATH:-$HOME/.ray/auth_token}" ]] && return 0
  "$RAY_BIN" get-auth-token --generate >/dev/null
}

# start_node NAME ARGS...: `ray start --block ARGS` in a new session; its pid (= session id) is recorded.
start_node() {
  local name=$1; shift
  setsid "$RAY_PYTHON" "$LOOPBACK_START" start --block --disable-usage-stats --node-ip-address 127.0.0.1 \
    --num-cpus "$CPUS_PER_NODE" "$@" >"$CLUSTER_DIR/$name.log" 2>&1 </dev/null &
  echo "$! $name" >>"$PIDS"
}

node_ports() {  # dashboard-agent ports of node i (head is 0)
  local i=$1
  echo --dashboard-agent-listen-port $((AGENT_PORT + 2 * i)) --dashboard-agent-grpc-port $((AGENT_PORT + 2 * i + 1))
}

wait_for_nodes() {  # until the GCS lists $1 alive nodes (or 90 s)
  local want=$1 deadline=$((SECONDS + 90))
  while ((SECONDS < deadline)); do
    local alive
    alive=$("$RAY_BIN" list nodes --address "http://127.0.0.1:$DASHBOARD_PORT" --filter "state=ALIVE" --format json 2>/dev/null |
      grep -o '"node_id"' | wc -l || true)
    ((alive >= want)) && return 0
    sleep 1
  done
  die "only ${alive:-0}/$want nodes came up; logs in $CLUSTER_DIR"
}

start() {
  local workers=${1:-1}
  [[ "$workers" =~ ^[0-9]+$ ]] || die "start N: N must be a number of worker nodes, got '$workers'"
  [[ -s "$PIDS" ]] && die "$PIDS exists: a cluster from this folder may be running; run '$0 stop' first"
  mkdir -p "$CLUSTER_DIR"
  ensure_token
  # shellcheck disable=SC2046
  start_node head --head --port "$GCS_PORT" --dashboard-host 127.0.0.1 --dashboard-port "$DASHBOARD_PORT" \
    --include-dashboard true --temp-dir "$CLUSTER_DIR/ray" $(node_ports 0)
  for ((i = 1; i <= workers; i++)); do
    # shellcheck disable=SC2046
    # A temp dir of its own, as a separate machine has: nodes sharing one unpack the same job's working_dir
    # into one folder, and a node that unpacks it later deletes the folder the driver runs in.
    start_node "worker-$i" --address "127.0.0.1:$GCS_PORT" --temp-dir "$CLUSTER_DIR/ray-$i" $(node_ports "$i")
  done
  wait_for_nodes $((workers + 1))
  echo "cluster up: GCS 127.0.0.1:$GCS_PORT, dashboard http://127.0.0.1:$DASHBOARD_PORT ($((workers + 1)) nodes)"
  echo "submit:     motionaug submit CONFIG --address http://127.0.0.1:$DASHBOARD_PORT"
}

session_pids() {  # every live process whose session id is $1
  ps -eo pid=,sid=,stat= | awk -v s="$1" '$2 == s && $3 !~ /^Z/ { print $1 }'
}

stop() {
  [[ -f "$PIDS" ]] || { echo "local-cluster: nothing to stop ($PIDS not found)"; return 0; }
  local sid name pids
  for signal in TERM KILL; do
    while read -r sid name; do
      pids=$(session_pids "$sid")
      [[ -n "$pids" ]] && kill "-$signal" $pids 2>/dev/null || true
    done <"$PIDS"
    [[ $signal == TERM ]] && sleep 2
  done
  rm -f "$PIDS"
  echo "local-cluster: stopped"
}

status() {
  [[ -f "$PIDS" ]] || { echo "local-cluster: not running"; return 0; }
  local sid name
  while read -r sid name; do
    echo "$name (session $sid): $(session_pids "$sid" | wc -l) processes"
  done <"$PIDS"
}

case "${1:-}" in
  start) start "${2:-1}" ;;
  stop) stop ;;
  status) status ;;
  *) die "usage: $0 start N | stop | status" ;;
esac
