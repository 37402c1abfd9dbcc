/*
 * Fake libhdeem for hdeem-watch's tests. It behaves as public code shows the real library behaving
 * (sources in hdeem.h and docs/sources.md): BLADE and six VR sensors sampled at their *real* rates
 * (default 1003.074 / 98.663 Sa/s as measured on Taurus, 6415.txt, not the nominal 1000 / 100), VR
 * samples taken 29.4 ms before their blade-clock time (Score-P's time_offset_vr), values in 0.125 W
 * steps, energy totals since power-on (no measurement needed) and since hdeem_start, start failing
 * while a measurement runs, asynchronous stop, a BMC buffer that overflows after buffer_s, slow
 * calls, lost connections, varying sensor-name spelling. It records every API call (hdeem_fake_calls,
 * HDEEM_FAKE_LOG) so tests can prove what a client did. Time is CLOCK_MONOTONIC + a test offset.
 *
 * The time model: sensor power is a step function of time (hdeem_fake_set_power). A sample's value
 * is the power at its start. Since power-on (P) blade sample k covers [P + k*db, P + (k+1)*db); a
 * measurement started at T restarts both grids: blade m covers [T + m*db, ...), VR m covers
 * [T - off + m*dv, ...) and is counted at T + (m+1)*dv. Energies are sums of samples x period.
 */
#define _POSIX_C_SOURCE 200809L
#include "hdeem.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define NSENS 7
#define NBLADE 1
#define NVR 6
#define MAXCHG 4096
#define POWERON_AGO_NS (3600LL * 1000000000LL)
#define LOGMAX 65536

static const char *canon[NSENS] = {"BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"};
static const char *lower_sp[NSENS] = {"blade", "cpu0", "cpu1", "ddr ab", "ddr cd", "ddr ef", "ddr gh"};
static const char *mixed[NSENS] = {"Blade", "Cpu0", "Cpu1", "Ddr_Ab", "Ddr_Cd", "Ddr_Ef", "Ddr_Gh"};

typedef struct {
    double t;      /* fake time (ns since first use) from which the power holds */
    double w;
} change_t;

typedef struct {   /* a sample grid: origin of sample 0, period, how early its values are taken */
    double origin, period, early;
} grid_t;

static struct {
    int ready;
    long long offset_ns;       /* added to CLOCK_MONOTONIC */
    long long mono0_ns;        /* monotonic at first use: fake time 0 */
    long long wall0_ns;        /* realtime at first use */
    change_t chg[NSENS][MAXCHG];
    int nchg[NSENS];
    int running, started;
    double start_t, stop_t;    /* fake times of the measurement's start and stop */
    double stopping_until;     /* status polling until this fake time */
    int connected, lost;
    long long fail_init, fail_calls, slow_calls, slow_ms, stop_ms, overflow, names_style, deny;
    long long blade_mhz, vr_mhz, vr_offset_us, buffer_s, blade_cap;
    char log[LOGMAX];
    size_t loglen;
    int ncalls;
} S;

static long long raw_clock(clockid_t id) {
    struct timespec ts;
    clock_gettime(id, &ts);
    return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static double q(double w) { return w <= 0 ? 0.0 : floor(w / 0.125 + 0.5) * 0.125; }

static void setup(void) {
    if (S.ready) return;
    static const double base[NSENS] = {100.0, 28.0, 24.0, 1.0, 1.125, 0.875, 1.5};
    S.ready = 1;
    S.mono0_ns = raw_clock(CLOCK_MONOTONIC);
    S.wall0_ns = raw_clock(CLOCK_REALTIME);
    for (int s = 0; s < NSENS; s++) {
        S.chg[s][0].t = -1e30;
        S.chg[s][0].w = q(base[s]);
        S.nchg[s] = 1;
    }
    S.stop_ms = 20;
    S.slow_ms = 300;
    S.blade_mhz = 1003074;
    S.vr_mhz = 98663;
    S.vr_offset_us = 29400;
    S.buffer_s = 8 * 3600;
    static const char *keys[] = {"FAIL_INIT", "FAIL_CALLS", "SLOW_CALLS", "SLOW_MS", "STOP_MS", "OVERFLOW",
                                 "NAMES_STYLE", "DENY", "BLADE_MHZ", "VR_MHZ", "VR_OFFSET_US", "BUFFER_S"};
    long long *slots[] = {&S.fail_init, &S.fail_calls, &S.slow_calls, &S.slow_ms, &S.stop_ms, &S.overflow,
                          &S.names_style, &S.deny, &S.blade_mhz, &S.vr_mhz, &S.vr_offset_us, &S.buffer_s};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
        char name[64];
        snprintf(name, sizeof name, "HDEEM_FAKE_%s", keys[i]);
        const char *v = getenv(name);
        if (v && *v) *slots[i] = atoll(v);
    }
}

static void logcall(const char *name) {
    setup();
    size_t n = strlen(name);
    if (S.loglen + n + 2 < LOGMAX) {
        if (S.loglen) S.log[S.loglen++] = ',';
        memcpy(S.log + S.loglen, name, n + 1);
        S.loglen += n;
    }
    S.ncalls++;
    const char *path = getenv("HDEEM_FAKE_LOG");
    if (path && *path) {
        FILE *f = fopen(path, "a");
        if (f) {
            fprintf(f, "%s\n", name);
            fclose(f);
        }
    }
}

/* fake time: ns since first use (double: grid arithmetic with non-integer periods) */
static double now_t(void) { return (double)(raw_clock(CLOCK_MONOTONIC) + S.offset_ns - S.mono0_ns); }
static double poweron_t(void) { return -(double)POWERON_AGO_NS; }
static double blade_period(void) { return 1e12 / (double)S.blade_mhz; }
static double vr_period(void) { return 1e12 / (double)S.vr_mhz; }
static double vr_early(void) { return (double)S.vr_offset_us * 1e3; }

static grid_t grid(int blade, double origin) {
    grid_t g = {origin, blade ? blade_period() : vr_period(), blade ? 0.0 : vr_early()};
    return g;
}

/* samples of a grid counted by fake time t */
static long long counted(grid_t g, double t) {
    double n = floor((t - g.origin) / g.period);
    return n < 0 ? 0 : (long long)n;
}

static double power_at(int s, double t) {
    int i = S.nchg[s] - 1;
    while (i > 0 && S.chg[s][i].t > t) i--;
    return S.chg[s][i].w;
}

static double value(int s, grid_t g, long long k) { return power_at(s, g.origin - g.early + (double)k * g.period); }

/* energy (J) of samples [a, b) of sensor s on grid g, with their min and max */
static double energy(int s, grid_t g, long long a, long long b, double *mn, double *mx) {
    double e = 0.0;
    *mn = INFINITY;
    *mx = -INFINITY;
    for (int i = 0; i < S.nchg[s]; i++) {
        double lo_t = S.chg[s][i].t, hi_t = i + 1 < S.nchg[s] ? S.chg[s][i + 1].t : INFINITY;
        /* samples whose value time origin - early + k*period lies in [lo_t, hi_t) */
        double x0 = (lo_t - g.origin + g.early) / g.period, x1 = (hi_t - g.origin + g.early) / g.period;
        long long lo = x0 < -1e18 ? a : (long long)ceil(x0), hi = x1 > 1e18 ? b : (long long)ceil(x1);
        if (lo < a) lo = a;
        if (hi > b) hi = b;
        if (hi > lo) {
            e += (double)(hi - lo) * S.chg[s][i].w * g.period * 1e-9;
            if (S.chg[s][i].w < *mn) *mn = S.chg[s][i].w;
            if (S.chg[s][i].w > *mx) *mx = S.chg[s][i].w;
        }
    }
    if (*mn > *mx) *mn = *mx = 0.0;
    return e;
}

static struct timespec to_timespec(double t) {
    long long wall = llround(t) + S.wall0_ns;
    struct timespec ts = {(time_t)(wall / 1000000000LL), (long)(wall % 1000000000LL)};
    return ts;
}

static void maybe_slow(void) {
    if (S.slow_calls > 0) {
        S.slow_calls--;
        struct timespec ts = {S.slow_ms / 1000, (S.slow_ms % 1000) * 1000000L};
        nanosleep(&ts, NULL);
    }
}

static int check_link(hdeem_bmc_data_t *bmc) {
    if (!bmc || !S.connected) return -5;
    if (S.lost) return -6;
    if (S.fail_calls > 0) {
        S.fail_calls--;
        S.lost = 1;   /* the connection stays broken until close + init */
        return -6;
    }
    return 0;
}

int hdeem_init(hdeem_bmc_data_t *bmc) {
    logcall("init");
    if (!bmc) return -1;
    int inband = !bmc->host || !*bmc->host;
    if (inband && (!bmc->hasGPIO || !bmc->hasPCIe)) return -22;   /* in-band needs GPIO/PCIe access */
    if (S.deny) return -13;
    if (S.fail_init > 0) {
        S.fail_init--;
        return -7;
    }
    const char **names = S.names_style == 1 ? lower_sp : S.names_style == 2 ? mixed : canon;
    bmc->nb_blade_sensors = NBLADE;
    bmc->nb_vr_sensors = NVR;
    for (int s = 0; s < NSENS; s++) {
        char *copy = strdup(names[s]);
        if (s < NBLADE) bmc->name_blade_sensors[s] = copy;
        else bmc->name_vr_sensors[s - NBLADE] = copy;
    }
    bmc->priv = &S;
    S.connected = 1;
    S.lost = 0;
    return 0;
}

void hdeem_close(hdeem_bmc_data_t *bmc) {
    logcall("close");
    if (!bmc) return;
    for (int s = 0; s < bmc->nb_blade_sensors && s < HDEEM_MAX_SENSORS; s++) free(bmc->name_blade_sensors[s]);
    for (int s = 0; s < bmc->nb_vr_sensors && s < HDEEM_MAX_SENSORS; s++) free(bmc->name_vr_sensors[s]);
    bmc->nb_blade_sensors = bmc->nb_vr_sensors = 0;
    bmc->priv = NULL;
    S.connected = 0;
}

static void start_now(void) {
    S.start_t = now_t();
    S.running = 1;
    S.started = 1;
    S.stopping_until = 0;
}

int hdeem_start(hdeem_bmc_data_t *bmc) {
    logcall("start");
    int rc = check_link(bmc);
    if (rc) return rc;
    if (S.running) return -16;   /* busy: start while running fails */
    start_now();
    return 0;
}

int hdeem_stop(hdeem_bmc_data_t *bmc) {
    logcall("stop");
    int rc = check_link(bmc);
    if (rc) return rc;
    if (!S.running) return -2;
    S.stop_t = now_t();
    S.running = 0;
    S.stopping_until = S.stop_t + (double)S.stop_ms * 1e6;   /* asynchronous: still polling a while */
    return 0;
}

int hdeem_clear(hdeem_bmc_data_t *bmc) {
    logcall("clear");
    int rc = check_link(bmc);
    if (rc) return rc;
    S.running = 0;      /* works on a running measurement too (callers then start again) */
    S.started = 0;
    S.stopping_until = 0;
    S.overflow = 0;
    return 0;
}

int hdeem_check_status(hdeem_bmc_data_t *bmc, hdeem_status_t *status) {
    logcall("check_status");
    int rc = check_link(bmc);
    if (rc) return rc;
    double t = now_t();
    int st = 0;
    if (S.running || t < S.stopping_until) st |= HDEEM_BMC_POLLING | HDEEM_FPGA_POLLING;
    if (S.overflow & 1) st |= HDEEM_BMC_OVERFLOW;
    if (S.overflow & 2) st |= HDEEM_FPGA_BLADE_OVERFLOW;
    if (S.overflow & 4) st |= HDEEM_FPGA_VR_OVERFLOW;
    if (S.started && (S.running ? t : S.stop_t) - S.start_t > (double)S.buffer_s * 1e9)
        st |= HDEEM_BMC_OVERFLOW;
    memset(status, 0, sizeof(*status));
    status->status = st;
    if (S.started) {
        status->start_time_blade = to_timespec(S.start_t);
        if (!S.running) status->stop_time_blade = to_timespec(S.stop_t);
    }
    return 0;
}

static void alloc_stats(hdeem_stats_reading_t *st) {
    hdeem_float_values_t *f[] = {&st->max_blade_values, &st->min_blade_values, &st->average_blade_values,
                                 &st->instant_blade_values, &st->max_vr_values, &st->min_vr_values,
                                 &st->average_vr_values, &st->instant_vr_values};
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++) f[i]->value = calloc(HDEEM_MAX_SENSORS, sizeof(float));
    st->energy_blade_values.value = calloc(HDEEM_MAX_SENSORS, sizeof(double));
    st->energy_vr_values.value = calloc(HDEEM_MAX_SENSORS, sizeof(double));
}

static int fill_stats(hdeem_stats_reading_t *st, int total) {
    double t = now_t();
    memset(st, 0, sizeof(*st));
    if (!total && !S.started) return -3;
    alloc_stats(st);
    double until = total || S.running ? t : S.stop_t;
    for (int blade = 1; blade >= 0; blade--) {
        grid_t g = grid(blade, total ? poweron_t() : S.start_t);
        long long n = counted(g, until);
        double read = g.origin - g.early + (double)n * g.period;   /* end of the last sample counted */
        if (blade) {
            st->nb_blade_values = (unsigned long long)n;
            st->read_time_blade = to_timespec(read);
        } else {
            st->nb_vr_values = (unsigned long long)n;
            st->read_time_vr = to_timespec(read);
        }
        for (int s = blade ? 0 : NBLADE; s < (blade ? NBLADE : NSENS); s++) {
            double mn, mx, e = energy(s, g, 0, n, &mn, &mx);
            double avg = n > 0 ? e / ((double)n * g.period * 1e-9) : 0.0;
            double inst = value(s, g, n > 0 ? n - 1 : 0);
            if (total) mn = mx = 0.0;   /* get_stats_total reports no min/max (Taurus printouts) */
            int i = blade ? s : s - NBLADE;
            if (blade) {
                st->energy_blade_values.value[i] = e;
                st->average_blade_values.value[i] = (float)avg;
                st->max_blade_values.value[i] = (float)mx;
                st->min_blade_values.value[i] = (float)mn;
                st->instant_blade_values.value[i] = (float)inst;
            } else {
                st->energy_vr_values.value[i] = e;
                st->average_vr_values.value[i] = (float)avg;
                st->max_vr_values.value[i] = (float)mx;
                st->min_vr_values.value[i] = (float)mn;
                st->instant_vr_values.value[i] = (float)inst;
            }
        }
    }
    return 0;
}

int hdeem_get_stats(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats) {
    logcall("get_stats");
    memset(stats, 0, sizeof(*stats));
    int rc = check_link(bmc);
    if (rc) return rc;
    maybe_slow();
    return fill_stats(stats, 0);
}

int hdeem_get_stats_total(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats) {
    logcall("get_stats_total");
    memset(stats, 0, sizeof(*stats));
    int rc = check_link(bmc);
    if (rc) return rc;
    maybe_slow();
    return fill_stats(stats, 1);
}

void hdeem_stats_free(hdeem_stats_reading_t *stats) {
    logcall("stats_free");
    if (!stats) return;
    hdeem_float_values_t *f[] = {&stats->max_blade_values, &stats->min_blade_values, &stats->average_blade_values,
                                 &stats->instant_blade_values, &stats->max_vr_values, &stats->min_vr_values,
                                 &stats->average_vr_values, &stats->instant_vr_values};
    for (size_t i = 0; i < sizeof f / sizeof f[0]; i++) {
        free(f[i]->value);
        f[i]->value = NULL;
    }
    free(stats->energy_blade_values.value);
    free(stats->energy_vr_values.value);
    stats->energy_blade_values.value = stats->energy_vr_values.value = NULL;
}

int hdeem_get_global(hdeem_bmc_data_t *bmc, hdeem_global_reading_t *global) {
    logcall("get_global");
    memset(global, 0, sizeof(*global));
    int rc = check_link(bmc);
    if (rc) return rc;
    if (!S.started) return -3;
    double until = S.running ? now_t() : S.stop_t;
    for (int blade = 1; blade >= 0; blade--) {
        grid_t g = grid(blade, S.start_t);
        long long n = counted(g, until), first = 0;
        if (blade && S.blade_cap > 0 && n > S.blade_cap) first = n - S.blade_cap;   /* ring buffer */
        long long kept = n - first;
        hdeem_power_sample_t *arr = calloc(kept > 0 ? (size_t)kept : 1, sizeof(hdeem_power_sample_t));
        if (!arr) return -12;
        for (long long i = 0; i < kept; i++)
            for (int s = blade ? 0 : NBLADE; s < (blade ? NBLADE : NSENS); s++)
                arr[i].value[blade ? s : s - NBLADE] = (float)value(s, g, first + i);
        if (blade) {
            global->nb_blade_values = (unsigned long)kept;
            global->blade_power = arr;
            global->first_blade_value = first + 1;
        } else {
            global->nb_vr_values = (unsigned long)kept;
            global->vr_power = arr;
        }
    }
    return 0;
}

void hdeem_data_free(hdeem_global_reading_t *global) {
    logcall("data_free");
    if (!global) return;
    free(global->blade_power);
    free(global->vr_power);
    global->blade_power = global->vr_power = NULL;
}

long long hdeem_fake_control(const char *key, long long value) {
    setup();
    struct { const char *name; long long *slot; } keys[] = {
        {"fail_init", &S.fail_init}, {"fail_calls", &S.fail_calls}, {"slow_calls", &S.slow_calls},
        {"slow_ms", &S.slow_ms}, {"stop_ms", &S.stop_ms}, {"overflow", &S.overflow},
        {"names_style", &S.names_style}, {"deny", &S.deny}, {"blade_mhz", &S.blade_mhz},
        {"vr_mhz", &S.vr_mhz}, {"vr_offset_us", &S.vr_offset_us}, {"buffer_s", &S.buffer_s},
        {"blade_cap", &S.blade_cap}};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (!strcmp(key, keys[i].name)) {
            *keys[i].slot = value;
            return 0;
        }
    if (!strcmp(key, "advance_ns")) S.offset_ns += value;
    else if (!strcmp(key, "clock_ns")) return (long long)now_t() + S.mono0_ns;
    else if (!strcmp(key, "wall_ns")) return llround(now_t()) + S.wall0_ns;
    else if (!strcmp(key, "running")) return S.running;
    else if (!strcmp(key, "run_external")) {
        if (value > 0) start_now();
        else if (value < 0) S.running = S.started = 0;   /* forget any measurement */
        else if (S.running) {
            S.stop_t = now_t();
            S.running = 0;
        }
    } else if (!strcmp(key, "log_reset")) {
        S.loglen = 0;
        S.log[0] = '\0';
        S.ncalls = 0;
    } else return -1;
    return 0;
}

int hdeem_fake_set_power(int sensor, double watts) {
    setup();
    if (sensor < 0 || sensor >= NSENS) return -1;
    double t = now_t();
    int n = S.nchg[sensor];
    if (n >= MAXCHG) return -2;
    S.chg[sensor][n].t = t;
    S.chg[sensor][n].w = q(watts);
    S.nchg[sensor] = n + 1;
    return 0;
}

int hdeem_fake_calls(char *buf, int len) {
    setup();
    if (buf && len > 0) {
        strncpy(buf, S.log, (size_t)len - 1);
        buf[len - 1] = '\0';
    }
    return S.ncalls;
}
