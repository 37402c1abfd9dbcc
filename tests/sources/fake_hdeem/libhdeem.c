/*
 * Fake libhdeem for hdeem-watch's tests: behaves like the real library as documented in
 * DESIGN.md section 5 — BLADE at 1000 Sa/s, six VR sensors at 100 Sa/s, values in 0.125 W steps,
 * energy totals since "power-on" and since start, start failing while running, asynchronous stop,
 * overflow flags, slow calls, lost connections, varying sensor-name spelling — with failures on
 * demand through hdeem_fake_control(). Time is CLOCK_MONOTONIC plus a test-controlled offset.
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

static const char *canon[NSENS] = {"BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"};
static const char *lower_sp[NSENS] = {"blade", "cpu0", "cpu1", "ddr ab", "ddr cd", "ddr ef", "ddr gh"};
static const char *mixed[NSENS] = {"Blade", "Cpu0", "Cpu1", "Ddr_Ab", "Ddr_Cd", "Ddr_Ef", "Ddr_Gh"};

typedef struct {
    long long k;   /* first sample index with this power */
    double w;
} change_t;

static struct {
    int ready;
    long long offset_ns;       /* added to CLOCK_MONOTONIC */
    long long mono0_ns;        /* monotonic at first use */
    long long wall0_ns;        /* realtime at first use */
    long long poweron_ns;      /* fake monotonic time of sample 0 */
    change_t chg[NSENS][MAXCHG];
    int nchg[NSENS];
    int running;
    long long start_k[2];      /* sample index (blade, vr) at start */
    long long stop_k[2];       /* at stop (valid when !running && started) */
    int started;
    long long stopping_until;  /* status polling until this fake time */
    int connected;
    int lost;
    long long fail_init, fail_calls, slow_calls, slow_ms, stop_ms, overflow, names_style, deny;
} S;

static long long raw_mono(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static long long raw_wall(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static double q(double w) { return w <= 0 ? 0.0 : floor(w / 0.125 + 0.5) * 0.125; }

static void setup(void) {
    if (S.ready) return;
    static const double base[NSENS] = {100.0, 28.0, 24.0, 1.0, 1.125, 0.875, 1.5};
    S.ready = 1;
    S.mono0_ns = raw_mono();
    S.wall0_ns = raw_wall();
    S.poweron_ns = S.mono0_ns - POWERON_AGO_NS;
    for (int s = 0; s < NSENS; s++) {
        S.chg[s][0].k = 0;
        S.chg[s][0].w = q(base[s]);
        S.nchg[s] = 1;
    }
    S.stop_ms = 20;
    S.slow_ms = 300;
    /* failures on demand from the environment too (for tests that run a real daemon process) */
    static const char *keys[] = {"FAIL_INIT", "FAIL_CALLS", "SLOW_CALLS", "SLOW_MS", "STOP_MS",
                                 "OVERFLOW", "NAMES_STYLE", "DENY"};
    long long *slots[] = {&S.fail_init, &S.fail_calls, &S.slow_calls, &S.slow_ms, &S.stop_ms,
                          &S.overflow, &S.names_style, &S.deny};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
        char name[64];
        snprintf(name, sizeof name, "HDEEM_FAKE_%s", keys[i]);
        const char *v = getenv(name);
        if (v && *v) *slots[i] = atoll(v);
    }
}

static long long now_ns(void) { return raw_mono() + S.offset_ns; }
static long long period_ns(int s) { return s < NBLADE ? 1000000LL : 10000000LL; }

/* samples of sensor s completed by fake time t (sample k covers [k, k+1) periods after power-on) */
static long long samples_at(int s, long long t) { return (t - S.poweron_ns) / period_ns(s); }

static double value_at(int s, long long k) {
    int i = S.nchg[s] - 1;
    while (i > 0 && S.chg[s][i].k > k) i--;
    return S.chg[s][i].w;
}

/* energy (J) of samples [0, n) of sensor s */
static double energy_upto(int s, long long n) {
    double e = 0.0, dt = period_ns(s) * 1e-9;
    for (int i = 0; i < S.nchg[s]; i++) {
        long long a = S.chg[s][i].k, b = (i + 1 < S.nchg[s]) ? S.chg[s][i + 1].k : n;
        if (b > n) b = n;
        if (b > a) e += (double)(b - a) * S.chg[s][i].w * dt;
    }
    return e;
}

static void minmax(int s, long long a, long long b, double *mn, double *mx) {
    *mn = INFINITY;
    *mx = -INFINITY;
    for (int i = 0; i < S.nchg[s]; i++) {
        long long lo = S.chg[s][i].k, hi = (i + 1 < S.nchg[s]) ? S.chg[s][i + 1].k : b;
        if (lo < a) lo = a;
        if (hi > b) hi = b;
        if (hi > lo) {
            if (S.chg[s][i].w < *mn) *mn = S.chg[s][i].w;
            if (S.chg[s][i].w > *mx) *mx = S.chg[s][i].w;
        }
    }
    if (*mn > *mx) *mn = *mx = 0.0;
}

static void to_timespec(long long fake_mono, struct timespec *ts) {
    long long wall = fake_mono - S.mono0_ns + S.wall0_ns;
    ts->tv_sec = wall / 1000000000LL;
    ts->tv_nsec = wall % 1000000000LL;
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
    setup();
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

int hdeem_close(hdeem_bmc_data_t *bmc) {
    if (!bmc) return -1;
    for (int s = 0; s < bmc->nb_blade_sensors && s < HDEEM_MAX_SENSORS; s++) free(bmc->name_blade_sensors[s]);
    for (int s = 0; s < bmc->nb_vr_sensors && s < HDEEM_MAX_SENSORS; s++) free(bmc->name_vr_sensors[s]);
    bmc->nb_blade_sensors = bmc->nb_vr_sensors = 0;
    bmc->priv = NULL;
    S.connected = 0;
    return 0;
}

int hdeem_start(hdeem_bmc_data_t *bmc) {
    int rc = check_link(bmc);
    if (rc) return rc;
    if (S.running) return -16;   /* busy: start while running fails */
    long long t = now_ns();
    S.start_k[0] = samples_at(0, t);
    S.start_k[1] = samples_at(1, t);
    S.running = 1;
    S.started = 1;
    return 0;
}

int hdeem_stop(hdeem_bmc_data_t *bmc) {
    int rc = check_link(bmc);
    if (rc) return rc;
    if (!S.running) return -2;
    long long t = now_ns();
    S.stop_k[0] = samples_at(0, t);
    S.stop_k[1] = samples_at(1, t);
    S.running = 0;
    S.stopping_until = t + S.stop_ms * 1000000LL;   /* asynchronous: still polling for a while */
    return 0;
}

int hdeem_clear(hdeem_bmc_data_t *bmc) {
    int rc = check_link(bmc);
    if (rc) return rc;
    S.running = 0;
    S.started = 0;
    S.stopping_until = 0;
    S.overflow = 0;
    return 0;
}

int hdeem_check_status(hdeem_bmc_data_t *bmc, hdeem_status_t *status) {
    int rc = check_link(bmc);
    if (rc) return rc;
    int st = 0;
    if (S.running || now_ns() < S.stopping_until) st |= HDEEM_BMC_POLLING | HDEEM_FPGA_POLLING;
    st |= (int)S.overflow & (HDEEM_BMC_OVERFLOW | HDEEM_FPGA_BLADE_OVERFLOW | HDEEM_FPGA_VR_OVERFLOW);
    status->status = st;
    return 0;
}

static int fill_stats(hdeem_stats_reading_t *st, int total) {
    long long t = now_ns();
    memset(st, 0, sizeof(*st));
    for (int g = 0; g < 2; g++) {
        int s0 = g == 0 ? 0 : NBLADE;
        long long n = samples_at(s0, t);
        long long a = 0, b = n;
        if (!total) {
            if (!S.started) return -3;
            a = S.start_k[g];
            b = S.running ? n : S.stop_k[g];
        }
        if (g == 0) st->nb_blade_values = (unsigned long long)(b - a);
        else st->nb_vr_values = (unsigned long long)(b - a);
        /* read time = end of the last sample counted */
        to_timespec(S.poweron_ns + b * period_ns(s0), g == 0 ? &st->read_time_blade : &st->read_time_vr);
        for (int s = s0; s < (g == 0 ? NBLADE : NSENS); s++) {
            double e = energy_upto(s, b) - energy_upto(s, a);
            double mn = 0, mx = 0;
            if (!total) minmax(s, a, b, &mn, &mx);
            double avg = b > a ? e / ((double)(b - a) * period_ns(s) * 1e-9) : 0.0;
            double inst = value_at(s, n > 0 ? n - 1 : 0);
            if (g == 0) {
                st->energy_blade_values.value[s] = e;
                st->average_blade_values.value[s] = (float)avg;
                st->max_blade_values.value[s] = (float)mx;
                st->min_blade_values.value[s] = (float)mn;
                st->instant_blade_values.value[s] = (float)inst;
            } else {
                st->energy_vr_values.value[s - NBLADE] = e;
                st->average_vr_values.value[s - NBLADE] = (float)avg;
                st->max_vr_values.value[s - NBLADE] = (float)mx;
                st->min_vr_values.value[s - NBLADE] = (float)mn;
                st->instant_vr_values.value[s - NBLADE] = (float)inst;
            }
        }
    }
    return 0;
}

int hdeem_get_stats(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats) {
    int rc = check_link(bmc);
    if (rc) return rc;
    maybe_slow();
    return fill_stats(stats, 0);
}

int hdeem_get_stats_total(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats) {
    int rc = check_link(bmc);
    if (rc) return rc;
    maybe_slow();
    return fill_stats(stats, 1);
}

void hdeem_stats_free(hdeem_stats_reading_t *stats) { (void)stats; }

int hdeem_get_global(hdeem_bmc_data_t *bmc, hdeem_global_reading_t *global) {
    int rc = check_link(bmc);
    if (rc) return rc;
    memset(global, 0, sizeof(*global));
    if (!S.started) return -3;
    long long t = now_ns();
    for (int g = 0; g < 2; g++) {
        int s0 = g == 0 ? 0 : NBLADE, s1 = g == 0 ? NBLADE : NSENS;
        long long a = S.start_k[g], b = S.running ? samples_at(s0, t) : S.stop_k[g];
        long long n = b - a;
        hdeem_power_sample_t *arr = calloc(n > 0 ? (size_t)n : 1, sizeof(hdeem_power_sample_t));
        if (!arr) return -12;
        for (long long i = 0; i < n; i++)
            for (int s = s0; s < s1; s++) arr[i].value[s - s0] = (float)value_at(s, a + i);
        if (g == 0) {
            global->nb_blade_values = (unsigned long)n;
            global->blade_power = arr;
        } else {
            global->nb_vr_values = (unsigned long)n;
            global->vr_power = arr;
        }
    }
    /* time of the first blade sample's end */
    to_timespec(S.poweron_ns + (S.start_k[0] + 1) * period_ns(0), &global->first_blade_value);
    return 0;
}

void hdeem_data_free(hdeem_global_reading_t *global) {
    if (!global) return;
    free(global->blade_power);
    free(global->vr_power);
    global->blade_power = global->vr_power = NULL;
}

long long hdeem_fake_control(const char *key, long long value) {
    setup();
    if (!strcmp(key, "fail_init")) S.fail_init = value;
    else if (!strcmp(key, "fail_calls")) S.fail_calls = value;
    else if (!strcmp(key, "slow_calls")) S.slow_calls = value;
    else if (!strcmp(key, "slow_ms")) S.slow_ms = value;
    else if (!strcmp(key, "stop_ms")) S.stop_ms = value;
    else if (!strcmp(key, "overflow")) S.overflow = value;
    else if (!strcmp(key, "names_style")) S.names_style = value;
    else if (!strcmp(key, "deny")) S.deny = value;
    else if (!strcmp(key, "advance_ns")) S.offset_ns += value;
    else if (!strcmp(key, "clock_ns")) return now_ns();
    else if (!strcmp(key, "running")) return S.running;
    else return -1;
    return 0;
}

int hdeem_fake_set_power(int sensor, double watts) {
    setup();
    if (sensor < 0 || sensor >= NSENS) return -1;
    long long k = samples_at(sensor, now_ns());
    int n = S.nchg[sensor];
    if (S.chg[sensor][n - 1].k == k) {
        S.chg[sensor][n - 1].w = q(watts);
        return 0;
    }
    if (n >= MAXCHG) return -2;
    S.chg[sensor][n].k = k;
    S.chg[sensor][n].w = q(watts);
    S.nchg[sensor] = n + 1;
    return 0;
}
