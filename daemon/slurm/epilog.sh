#!/bin/sh
# hdeem-watch SLURM Epilog (slurm.conf: Epilog=/path/to/daemon/slurm/epilog.sh).
#
# Runs as root on each node of a job after it ends. It appends the finished job record (start and
# end wall-clock ns, user, nodes, exit code) to $HDEEM_WATCH_HOOK_DIR/jobs.jsonl, so energy can be
# attributed to jobs afterwards, and stops the daemon the Prolog started for this job (SIGTERM,
# SIGKILL after 10 s); a daemon that was already running is left alone.
# Settings as for prolog.sh. The hook always exits 0.
CONF=${HDEEM_WATCH_HOOK_CONF:-/etc/hdeem-watch/slurm-hooks.env}
if [ -r "$CONF" ]; then
    set -a
    . "$CONF"
    set +a
fi
"${HDEEM_WATCH_PYTHON:-python3}" -m hdeem_watch.slurm epilog || true
exit 0
