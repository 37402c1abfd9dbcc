#!/bin/sh
# hdeem-watch SLURM TaskEpilog (optional; slurm.conf: TaskEpilog=/opt/hdeem-watch/slurm/task-epilog.sh).
#
# Runs as the job's user after each task and prints the job's DRAM energy so far on this node to
# the task's output (the end of the job's output file for a batch job), e.g.
#   hdeem-watch: job 4242 on node7: DRAM 1234.5 J (above idle 210.3 J) over 61.2 s, mean 20.2 W
# It only reads from the daemon (job.get); settings as for prolog.sh. Always exits 0.
. "$(dirname "$0")/hook-common.sh"
hook_run task-epilog
exit 0
