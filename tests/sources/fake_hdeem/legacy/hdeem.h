/*
 * LEGACY fake hdeem.h (hdeem-watch before issue 14), kept only to check that the shim still builds
 * its energy path against a header whose structs differ (first_blade_value a timespec, int
 * hdeem_close, no status times). Compile-only: no library implements it.
 *
 * The real header ships with Bull/Atos HDEEM and is not public. This one follows the API described
 * in hdeem-watch's DESIGN.md section 5 (function names, field names, macros); the types and layouts
 * are plausible guesses. hdeem-watch never depends on them from Python: every layout assumption lives
 * in src/hdeem_watch/sources/hdeem_shim.c, compiled against whichever hdeem.h is installed.
 *
 * Test controls (not part of the real API): hdeem_fake_control(), hdeem_fake_set_power().
 */
#ifndef HDEEM_H
#define HDEEM_H

#include <stddef.h>
#include <time.h>

#define HDEEM_MAX_SENSORS 16

/* status bits */
#define HDEEM_BMC_POLLING        0x01
#define HDEEM_FPGA_POLLING       0x02
#define HDEEM_BMC_OVERFLOW       0x04
#define HDEEM_FPGA_BLADE_OVERFLOW 0x08
#define HDEEM_FPGA_VR_OVERFLOW   0x10

/* the macros take the int status word (hdeem_status_t.status), as public wrappers use them */
#define IsBmcPolling(s)        (((s) & HDEEM_BMC_POLLING) != 0)
#define IsFpgaPolling(s)       (((s) & HDEEM_FPGA_POLLING) != 0)
#define IsBmcOverflow(s)       (((s) & HDEEM_BMC_OVERFLOW) != 0)
#define IsFpgaBladeOverflow(s) (((s) & HDEEM_FPGA_BLADE_OVERFLOW) != 0)
#define IsFpgaVrOverflow(s)    (((s) & HDEEM_FPGA_VR_OVERFLOW) != 0)

typedef struct {
    char *host;           /* NULL or "" = in-band */
    char *user;
    char *password;
    int hasGPIO;          /* in-band access: 1; out-of-band: 0 (the caller must set it) */
    int hasPCIe;
    int nb_blade_sensors;
    int nb_vr_sensors;
    char *name_blade_sensors[HDEEM_MAX_SENSORS];
    char *name_vr_sensors[HDEEM_MAX_SENSORS];
    void *priv;           /* library state */
} hdeem_bmc_data_t;

typedef struct {
    int status;
} hdeem_status_t;

typedef struct {
    float value[HDEEM_MAX_SENSORS];
} hdeem_sensor_values_t;

typedef struct {
    hdeem_sensor_values_t max_blade_values, min_blade_values, average_blade_values, instant_blade_values;
    hdeem_sensor_values_t max_vr_values, min_vr_values, average_vr_values, instant_vr_values;
    struct {
        double value[HDEEM_MAX_SENSORS];
    } energy_blade_values, energy_vr_values;
    unsigned long long nb_blade_values;
    unsigned long long nb_vr_values;
    struct timespec read_time_blade;
    struct timespec read_time_vr;
} hdeem_stats_reading_t;

typedef struct {
    float value[HDEEM_MAX_SENSORS];
} hdeem_power_sample_t;

typedef struct {
    unsigned long nb_blade_values;
    unsigned long nb_vr_values;
    hdeem_power_sample_t *blade_power;
    hdeem_power_sample_t *vr_power;
    struct timespec first_blade_value;
} hdeem_global_reading_t;

int hdeem_init(hdeem_bmc_data_t *bmc);
int hdeem_close(hdeem_bmc_data_t *bmc);
int hdeem_start(hdeem_bmc_data_t *bmc);
int hdeem_stop(hdeem_bmc_data_t *bmc);
int hdeem_clear(hdeem_bmc_data_t *bmc);
int hdeem_check_status(hdeem_bmc_data_t *bmc, hdeem_status_t *status);
int hdeem_get_global(hdeem_bmc_data_t *bmc, hdeem_global_reading_t *global);
void hdeem_data_free(hdeem_global_reading_t *global);
int hdeem_get_stats(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats);
int hdeem_get_stats_total(hdeem_bmc_data_t *bmc, hdeem_stats_reading_t *stats);
void hdeem_stats_free(hdeem_stats_reading_t *stats);

/* ---- fake-only test controls ---- */
/* keys: "fail_init" (next n inits fail), "fail_calls" (next n get_stats* calls fail: connection
 * lost until re-init), "slow_calls" (next n get_stats* calls sleep "slow_ms"), "slow_ms",
 * "stop_ms" (stop takes this long: status stays polling), "overflow" (status overflow bits),
 * "names_style" (0 canonical, 1 "ddr ab" lower case with spaces, 2 "Ddr_Ab"), "advance_ns" (adds to
 * the fake clock), "deny" (init fails with permission denied), "clock_ns" (read: current fake
 * monotonic ns). Returns the value read or 0. The same keys, upper-cased with the prefix HDEEM_FAKE_
 * (e.g. HDEEM_FAKE_DENY=1, HDEEM_FAKE_NAMES_STYLE=1), are read from the environment at first use. */
long long hdeem_fake_control(const char *key, long long value);
/* set sensor index s (0 = BLADE, 1.. = VR in name order) to watts from the current fake time on */
int hdeem_fake_set_power(int sensor, double watts);

#endif
