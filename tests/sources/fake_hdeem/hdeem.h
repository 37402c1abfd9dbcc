/*
 * Fake hdeem.h for hdeem-watch's tests, written to the semantics public code shows for the real,
 * non-public Bull/Atos header (see docs/sources.md: the public code that uses libhdeem, cited there):
 *
 * - hdeem_close() returns nothing: public callers never use its result (tud-zih-energy/phdeem
 *   src/phdeem.c stores every other call's result but not this one; tud-zih-energy/hdeem_cxx
 *   include/hdeem_cxx.hpp calls it as a statement). Declared void here, so `int rc = hdeem_close()`
 *   does not compile against it.
 * - hdeem_global_reading_t.first_blade_value is an integer sample index (phdeem
 *   src/example/testPhdeem.c prints `i + readings.first_blade_value - 1` with %lld).
 * - hdeem_status_t has start_time_blade / stop_time_blade (struct timespec); Score-P's HDEEM plugin
 *   (score-p/scorep_plugin_hdeem hdeem_plugin.cpp) derives the sampling period from them as
 *   duration / samples, and shifts VR samples by -(35000 - 5600) us.
 * - the status macros take the int status word (hdeem_cxx connection::stop, pwrapi pwr_hdeemdev.c).
 * - nb_*_values of a global reading are unsigned long (phdeem commit 1a143e3 "%lu").
 *
 * Layouts (field order, array vs pointer) are guesses: the shim must go through fields by name.
 * Test controls (not part of the real API): hdeem_fake_control(), hdeem_fake_set_power(),
 * hdeem_fake_calls().
 */
#ifndef HDEEM_H
#define HDEEM_H

#include <stddef.h>
#include <time.h>

#define HDEEM_MAX_SENSORS 16

/* status bits (the real values are not public; only the macros are used by callers) */
#define HDEEM_BMC_POLLING         0x100
#define HDEEM_FPGA_POLLING        0x200
#define HDEEM_BMC_OVERFLOW        0x400
#define HDEEM_FPGA_BLADE_OVERFLOW 0x800
#define HDEEM_FPGA_VR_OVERFLOW    0x1000

#define IsBmcPolling(s)        (((s) & HDEEM_BMC_POLLING) != 0)
#define IsFpgaPolling(s)       (((s) & HDEEM_FPGA_POLLING) != 0)
#define IsBmcOverflow(s)       (((s) & HDEEM_BMC_OVERFLOW) != 0)
#define IsFpgaBladeOverflow(s) (((s) & HDEEM_FPGA_BLADE_OVERFLOW) != 0)
#define IsFpgaVrOverflow(s)    (((s) & HDEEM_FPGA_VR_OVERFLOW) != 0)

typedef struct hdeem_bmc_data {
    void *priv;           /* library state (first, so a wrong field order in the shim would show) */
    char *host;           /* NULL or "" = in-band */
    char *user;
    char *password;
    int hasGPIO;          /* in-band access: 1; out-of-band: 0 */
    int hasPCIe;
    int nb_blade_sensors;
    int nb_vr_sensors;
    char *name_blade_sensors[HDEEM_MAX_SENSORS];
    char *name_vr_sensors[HDEEM_MAX_SENSORS];
} hdeem_bmc_data_t;

typedef struct {
    struct timespec start_time_blade;
    struct timespec stop_time_blade;   /* {0, 0} while the measurement runs */
    int status;
} hdeem_status_t;

typedef struct {
    float *value;                      /* library-owned (freed by hdeem_stats_free) */
} hdeem_float_values_t;

typedef struct {
    double *value;
} hdeem_double_values_t;

typedef struct {
    unsigned long long nb_blade_values;
    unsigned long long nb_vr_values;
    struct timespec read_time_blade;
    struct timespec read_time_vr;
    hdeem_float_values_t max_blade_values, min_blade_values, average_blade_values, instant_blade_values;
    hdeem_float_values_t max_vr_values, min_vr_values, average_vr_values, instant_vr_values;
    hdeem_double_values_t energy_blade_values, energy_vr_values;
} hdeem_stats_reading_t;

typedef struct {
    float value[HDEEM_MAX_SENSORS];
} hdeem_power_sample_t;

typedef struct {
    long long first_blade_value;       /* index (1-based, since hdeem_start) of blade_power[0] */
    unsigned long nb_blade_values;
    unsigned long nb_vr_values;
    hdeem_power_sample_t *blade_power;
    hdeem_power_sample_t *vr_power;
} hdeem_global_reading_t;

int hdeem_init(hdeem_bmc_data_t *bmc);
void hdeem_close(hdeem_bmc_data_t *bmc);
int hdeem_start(hdeem_bmc_data_t *bmc);
int hdeem_stop(hdeem_bmc_data_t *bmc);
int hdeem_clear(hdeem_bmc_data_t *bmc);
int hdeem_check_status(hdeem_bmc_data_t *bmc, hdeem_status_t *status);
int hdeem_get_global(hdeem_bmc_data_t *bmc, hdeem_global_reading_t *global);
void hdeem_data_free(hdeem_global_reading_t *global);
int hdeem_get_stats(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats);
int hdeem_get_stats_total(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats);
void hdeem_stats_free(hdeem_stats_reading_t *stats);

/* ---- fake-only test controls ----
 * hdeem_fake_control(key, value) keys: "fail_init" (next n inits fail), "fail_calls" (next n
 * get_stats* calls fail: connection lost until re-init), "slow_calls" / "slow_ms" (next n get_stats*
 * calls sleep), "stop_ms" (stop is asynchronous: status keeps polling this long), "overflow" (force
 * the overflow bits 1 BMC, 2 blade, 4 VR), "names_style" (0 canonical, 1 "ddr ab", 2 "Ddr_Ab"),
 * "deny" (init fails with -13), "advance_ns" (adds to the fake clock), "blade_mhz" / "vr_mhz" (real
 * sampling rates in mSa/s, default 1003074 and 98663: the Taurus capture 6415.txt), "vr_offset_us"
 * (how early VR samples are taken, default 29400), "buffer_s" (BMC buffer length; a measurement
 * running longer overflows, default 8 h), "blade_cap" (the global buffer keeps only the last n blade
 * samples; 0 = all), "run_external" (1: start a measurement as another tool would, 0: stop it, -1: forget any; not
 * logged),
 * "log_reset". Reads: "clock_ns" (fake monotonic ns), "wall_ns" (fake wall ns), "running".
 * The keys upper-cased with the prefix HDEEM_FAKE_ are read from the environment at first use;
 * HDEEM_FAKE_LOG=path appends every API call's name to that file.
 */
long long hdeem_fake_control(const char *key, long long value);
/* set sensor s (0 = BLADE, 1.. = VR in name order) to watts from the current fake time on */
int hdeem_fake_set_power(int sensor, double watts);
/* the API calls made since the last log_reset, comma-separated, into buf; returns their number */
int hdeem_fake_calls(char *buf, int len);

#endif
