#!/bin/sh
# hdeem-watch: print a SLURM job's DRAM energy at the end of its output (docs/slurm.md).
#
# In a batch script, wrap the last command, or call it alone as the last line:
#     /opt/hdeem-watch/slurm/dram-energy.sh srun ./app      # runs srun ./app, then prints; keeps its exit status
#     /opt/hdeem-watch/slurm/dram-energy.sh                 # prints only
# It prints one line per node of the allocation: the job's DRAM energy so far, above the idle
# baseline, and its mean power, from each node's daemon (hdeem-watch jobs --job $SLURM_JOB_ID), each
# node asked with a timeout of a few seconds. (A TaskEpilog cannot do this: SLURM discards a
# TaskEpilog's output.) Uses HDEEM_WATCH_PYTHON from /etc/hdeem-watch/slurm-hooks.env.
status=0
if [ "$#" -gt 0 ]; then
    "$@"
    status=$?
fi
HOOK_CONF=${HDEEM_WATCH_HOOK_CONF:-/etc/hdeem-watch/slurm-hooks.env}
if [ -z "${HDEEM_WATCH_PYTHON:-}" ] && [ -r "$HOOK_CONF" ]; then
    HDEEM_WATCH_PYTHON=$(sed -n 's/^HDEEM_WATCH_PYTHON=//p' "$HOOK_CONF" | tail -n 1)
fi
if [ -n "${SLURM_JOB_ID:-}" ] && [ -x "${HDEEM_WATCH_PYTHON:-}" ]; then
    echo "--- hdeem-watch: DRAM energy of job $SLURM_JOB_ID"
    "$HDEEM_WATCH_PYTHON" -m hdeem_watch jobs --job "$SLURM_JOB_ID" --timeout 3 || true
else
    echo "hdeem-watch: no DRAM energy (not in a SLURM job, or HDEEM_WATCH_PYTHON not set in $HOOK_CONF)" >&2
fi
exit "$status"
