#!/bin/sh
# hdeem-watch SLURM Prolog (slurm.conf: Prolog=/path/to/daemon/slurm/prolog.sh, PrologFlags=Alloc).
#
# Runs as root on each node of a job before it starts. It makes sure an hdeem-watch daemon watches
# the node during the job and records the job's start:
#   - a daemon already answers on the control endpoint (e.g. the systemd service): it is used; with
#     HDEEM_WATCH_PROLOG_BASELINE_S > 0 it first measures a quiet baseline for that many seconds;
#   - none answers and HDEEM_WATCH_START_DAEMON=1: one is started for the job
#     (hdeem-watch daemon --source $HDEEM_WATCH_SOURCE ...) and the Epilog stops it;
#   - otherwise only the job record is written.
# The record job-<id>.json goes to $HDEEM_WATCH_HOOK_DIR (default /run/hdeem-watch/slurm).
# Settings: HDEEM_WATCH_* variables, read from $HDEEM_WATCH_HOOK_CONF
# (default /etc/hdeem-watch/slurm-hooks.env, shell syntax), see docs/bench.md.
# The hook always exits 0: a failing Prolog would drain the node.
CONF=${HDEEM_WATCH_HOOK_CONF:-/etc/hdeem-watch/slurm-hooks.env}
if [ -r "$CONF" ]; then
    set -a
    . "$CONF"
    set +a
fi
"${HDEEM_WATCH_PYTHON:-python3}" -m hdeem_watch.slurm prolog || true
exit 0
