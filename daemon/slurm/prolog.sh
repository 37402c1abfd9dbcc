#!/bin/sh
# hdeem-watch SLURM Prolog (slurm.conf: Prolog=/opt/hdeem-watch/slurm/prolog.sh; docs/slurm.md).
#
# Runs as root on each node of a job before it starts and opens the job's window in the node's
# hdeem-watch daemon (job.start): from then on the daemon integrates every sensor over the job.
# The daemon's endpoints come from its own config file (HDEEM_WATCH_CONFIG, default
# /etc/hdeem-watch/hdeem-watchd.toml); the hooks' settings from /etc/hdeem-watch/slurm-hooks.env
# (HDEEM_WATCH_HOOK_CONF), which must set HDEEM_WATCH_PYTHON to the absolute path of a Python >= 3.11
# that has hdeem_watch installed. Bounded in time (HDEEM_WATCH_HOOK_TIMEOUT_S, default 30 s) and
# always exit 0 (a failing Prolog drains the node); failures are logged to syslog.
. "$(dirname "$0")/hook-common.sh"
hook_run prolog
exit 0
