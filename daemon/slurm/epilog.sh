#!/bin/sh
# hdeem-watch SLURM Epilog (slurm.conf: Epilog=/opt/hdeem-watch/slurm/epilog.sh; docs/slurm.md).
#
# Runs as root on each node of a job after it ends and closes the job's window in the node's
# hdeem-watch daemon (job.stop with SLURM_JOB_EXIT_CODE): the daemon stores the job's energy per
# sensor. A daemon that does not answer gets the stop from the next hook. Settings as for
# prolog.sh; bounded in time and always exit 0; failures are logged to syslog.
. "$(dirname "$0")/hook-common.sh"
hook_run epilog
exit 0
