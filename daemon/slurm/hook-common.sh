# Shared part of the hdeem-watch SLURM hooks (sourced by prolog.sh, epilog.sh and dram-energy.sh).
# POSIX sh. Reads the hooks' settings file, checks the interpreter, runs one action of
# `python -m hdeem_watch.slurm` under a hard timeout and logs any failure to syslog (logger).
# Never exits non-zero: SLURM drains a node whose Prolog fails.
HOOK_CONF=${HDEEM_WATCH_HOOK_CONF:-/etc/hdeem-watch/slurm-hooks.env}
if [ -r "$HOOK_CONF" ]; then
    set -a
    . "$HOOK_CONF"
    set +a
fi
PATH=/usr/bin:/bin:/usr/sbin:/sbin${PATH:+:$PATH}   # slurmd runs hooks with no search path set

hook_log() {   # one line to syslog (daemon.err, tag hdeem-watch-slurm) and to stderr
    logger -t hdeem-watch-slurm -p daemon.err ${HDEEM_WATCH_LOG_SOCKET:+-u "$HDEEM_WATCH_LOG_SOCKET"} -- "$*" \
        2>/dev/null || true
    echo "hdeem-watch-slurm: $*" >&2
}

hook_run() {   # hook_run ACTION: the Python side of the hook, bounded in time
    action=$1
    python=${HDEEM_WATCH_PYTHON:-}
    case "$python" in
        /*) ;;
        *) hook_log "$action job ${SLURM_JOB_ID:-?}: HDEEM_WATCH_PYTHON='$python' is not an absolute path" \
               "(set it in $HOOK_CONF at install); the job is not measured"
           return 0 ;;
    esac
    if [ ! -x "$python" ]; then
        hook_log "$action job ${SLURM_JOB_ID:-?}: the interpreter $python does not exist or is not executable" \
            "(HDEEM_WATCH_PYTHON in $HOOK_CONF); the job is not measured"
        return 0
    fi
    limit=${HDEEM_WATCH_HOOK_TIMEOUT_S:-30}
    output=$(timeout -k 2 "$limit" "$python" -m hdeem_watch.slurm "$action" 2>&1)
    status=$?
    if [ "$status" -ne 0 ]; then
        [ "$status" -eq 124 ] && output="timed out after $limit s (HDEEM_WATCH_HOOK_TIMEOUT_S)"
        hook_log "$action job ${SLURM_JOB_ID:-?}: $python -m hdeem_watch.slurm $action failed (exit $status):" \
            "$(printf '%s' "$output" | tail -n 3 | tr '\n' ' ')"
    fi
    return 0
}
