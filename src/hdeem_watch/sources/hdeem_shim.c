/*
 * hdeem-watch's shim over libhdeem: flat C functions with plain types, loaded with ctypes.
 *
 * hdeem.h (Bull/Atos) is not public. EVERY assumption about it is in this file, compiled on the node
 * against the installed header:
 *   cc -shared -fPIC -O2 hdeem_shim.c -I<include> -L<lib> -lhdeem -lfreeipmi -lrt -o libhdeem_shim.so
 * The assumptions are what public code compiled against the real header shows (tud-zih-energy/phdeem,
 * tud-zih-energy/hdeem_cxx, tud-zih-energy/metricq-source-hdeem, score-p/scorep_plugin_hdeem,
 * tud-zih-energy/pwrapi-ref; see docs/sources.md), and the shim depends on nothing public code
 * leaves open: it never uses a result no public caller uses (hdeem_close, hdeem_data_free and
 * hdeem_stats_free are called as statements), reads integers into long long, goes through fields
 * by name, and keeps three function sets apart so one can fail to build without the others:
 *
 *  - core (always): hdeem_init/close/start/stop/clear/check_status (the int word status.status and
 *    the IsBmcPolling... macros), get_stats/get_stats_total/stats_free (stats.{max,min,average,
 *    instant}_{blade,vr}_values.value[s] in W, energy_{blade,vr}_values.value[s] in J,
 *    nb_{blade,vr}_values, read_time_{blade,vr} as struct timespec), bmc.{host,user,password,
 *    nb_blade_sensors,nb_vr_sensors,name_blade_sensors[i],name_vr_sensors[i]}, and bmc.hasGPIO /
 *    hasPCIe (1 in-band, 0 out-of-band; -DHWS_NO_GPIO_FIELDS for a header without them).
 *  - status times (unless -DHWS_NO_STATUS_TIMES): status.start_time_blade / stop_time_blade as
 *    struct timespec (Score-P's hdeem_plugin.cpp derives the sampling periods from them).
 *  - global readings (unless -DHWS_NO_GLOBAL): hdeem_get_global / hdeem_data_free,
 *    global.first_blade_value an integer sample index (phdeem testPhdeem.c), nb_{blade,vr}_values,
 *    {blade,vr}_power[i].value[s]; hdeem_data_free() also after a failed hdeem_get_global.
 *
 * hdeem_lib.build_shim compiles with every set first and drops the sets that do not compile, so the
 * energy path (core) works against any header whose core fields are as above. hws_features() says
 * which sets were built. Sensors are numbered blade sensors first, then VR sensors. Times are
 * wall-clock ns.
 */
#include <hdeem.h>

#include <stdlib.h>
#include <string.h>
#include <time.h>

#define HWS_BMC_POLLING 0x01
#define HWS_FPGA_POLLING 0x02
#define HWS_BMC_OVERFLOW 0x04
#define HWS_BLADE_OVERFLOW 0x08
#define HWS_VR_OVERFLOW 0x10

#define HWS_FEATURE_STATUS_TIMES 0x01
#define HWS_FEATURE_GLOBAL 0x02

typedef struct {
    hdeem_bmc_data_t bmc;
    char *host, *user, *password;
    void *global;   /* hdeem_global_reading_t * of the global set, or NULL */
} hws_t;

static long long ts_ns(struct timespec ts) { return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec; }

static char *dup_or_null(const char *s) { return (s && *s) ? strdup(s) : NULL; }

int hws_abi_version(void) { return 2; }

int hws_features(void) {
    int f = 0;
#ifndef HWS_NO_STATUS_TIMES
    f |= HWS_FEATURE_STATUS_TIMES;
#endif
#ifndef HWS_NO_GLOBAL
    f |= HWS_FEATURE_GLOBAL;
#endif
    return f;
}

static void global_release(hws_t *h);

/* Connect; returns a handle, or NULL with *err = hdeem_init's code (or -12 out of memory). A failed
 * hdeem_init is followed by hdeem_close before the handle is freed. */
void *hws_open(const char *host, const char *user, const char *password, int *err) {
    hws_t *h = calloc(1, sizeof(hws_t));
    if (!h) {
        *err = -12;
        return NULL;
    }
    h->host = dup_or_null(host);
    h->user = dup_or_null(user);
    h->password = dup_or_null(password);
    h->bmc.host = h->host;
    h->bmc.user = h->user;
    h->bmc.password = h->password;
#ifndef HWS_NO_GPIO_FIELDS
    h->bmc.hasGPIO = h->host ? 0 : 1;   /* in-band: through GPIO/PCIe; out-of-band: IPMI over LAN */
    h->bmc.hasPCIe = h->host ? 0 : 1;
#endif
    int rc = hdeem_init(&h->bmc);
    if (rc != 0) {
        /* as hdeem_cxx does (commit 5b77f10, connection::init): "not suggested by the manual [...] we
         * assume we might be leaking FDs if we don't close" */
        hdeem_close(&h->bmc);
        free(h->host);
        free(h->user);
        free(h->password);
        free(h);
        *err = rc;
        return NULL;
    }
    *err = 0;
    return h;
}

/* Disconnect and free the handle. hdeem_close's result is not used (no public caller uses one). */
void hws_close(void *handle) {
    hws_t *h = handle;
    if (!h) return;
    global_release(h);
    hdeem_close(&h->bmc);
    if (h->password) memset(h->password, 0, strlen(h->password));
    free(h->host);
    free(h->user);
    free(h->password);
    free(h);
}

int hws_sensor_count(void *handle, int *nb_blade, int *nb_vr) {
    hws_t *h = handle;
    *nb_blade = h->bmc.nb_blade_sensors;
    *nb_vr = h->bmc.nb_vr_sensors;
    return 0;
}

int hws_sensor_name(void *handle, int index, char *buf, int len) {
    hws_t *h = handle;
    const char *name = NULL;
    if (len <= 0 || index < 0) return -1;
    if (index < h->bmc.nb_blade_sensors) name = h->bmc.name_blade_sensors[index];
    else if (index < h->bmc.nb_blade_sensors + h->bmc.nb_vr_sensors)
        name = h->bmc.name_vr_sensors[index - h->bmc.nb_blade_sensors];
    else return -1;
    if (!name) name = "";
    strncpy(buf, name, (size_t)len - 1);
    buf[len - 1] = '\0';
    return 0;
}

int hws_start(void *handle) { return hdeem_start(&((hws_t *)handle)->bmc); }
int hws_stop(void *handle) { return hdeem_stop(&((hws_t *)handle)->bmc); }
int hws_clear(void *handle) { return hdeem_clear(&((hws_t *)handle)->bmc); }

/*
 * Status flags (HWS_* bits) and, with the status-times set, the measurement's start and stop times
 * (wall ns; 0 where the library reports none). Without that set both times are -1.
 */
int hws_status(void *handle, int *flags, long long *start_ns, long long *stop_ns) {
    hws_t *h = handle;
    hdeem_status_t st;
    memset(&st, 0, sizeof(st));
    int rc = hdeem_check_status(&h->bmc, &st);
    if (rc != 0) return rc;
    int f = 0, s = st.status;
    if (IsBmcPolling(s)) f |= HWS_BMC_POLLING;
    if (IsFpgaPolling(s)) f |= HWS_FPGA_POLLING;
    if (IsBmcOverflow(s)) f |= HWS_BMC_OVERFLOW;
    if (IsFpgaBladeOverflow(s)) f |= HWS_BLADE_OVERFLOW;
    if (IsFpgaVrOverflow(s)) f |= HWS_VR_OVERFLOW;
    *flags = f;
#ifndef HWS_NO_STATUS_TIMES
    *start_ns = ts_ns(st.start_time_blade);
    *stop_ns = ts_ns(st.stop_time_blade);
#else
    *start_ns = -1;
    *stop_ns = -1;
#endif
    return 0;
}

/*
 * Statistics since start (total = 0) or since power-on (total = 1). Arrays have room for n sensors
 * (blade first); counts[2] = samples (blade, vr); read_ns[2] = read times (blade, vr).
 */
int hws_stats(void *handle, int total, int n, double *energy_j, double *avg_w, double *max_w, double *min_w,
              double *instant_w, long long *counts, long long *read_ns) {
    hws_t *h = handle;
    hdeem_stats_reading_t st;
    memset(&st, 0, sizeof(st));
    int rc = total ? hdeem_get_stats_total(&h->bmc, &st) : hdeem_get_stats(&h->bmc, &st);
    if (rc != 0) {
        hdeem_stats_free(&st);   /* also after a failure (hdeem_cxx commit 5b77f10) */
        return rc;
    }
    int nb = h->bmc.nb_blade_sensors, nv = h->bmc.nb_vr_sensors;
    for (int i = 0; i < n && i < nb + nv; i++) {
        int blade = i < nb;
        int s = blade ? i : i - nb;
        energy_j[i] = blade ? st.energy_blade_values.value[s] : st.energy_vr_values.value[s];
        avg_w[i] = blade ? st.average_blade_values.value[s] : st.average_vr_values.value[s];
        max_w[i] = blade ? st.max_blade_values.value[s] : st.max_vr_values.value[s];
        min_w[i] = blade ? st.min_blade_values.value[s] : st.min_vr_values.value[s];
        instant_w[i] = blade ? st.instant_blade_values.value[s] : st.instant_vr_values.value[s];
    }
    counts[0] = (long long)st.nb_blade_values;
    counts[1] = (long long)st.nb_vr_values;
    read_ns[0] = ts_ns(st.read_time_blade);
    read_ns[1] = ts_ns(st.read_time_vr);
    hdeem_stats_free(&st);
    return 0;
}

#ifndef HWS_NO_GLOBAL
/* ---- the global-readings set ---------------------------------------------------------------- */
static void global_release(hws_t *h) {
    if (h->global) {
        hdeem_data_free((hdeem_global_reading_t *)h->global);
        free(h->global);
        h->global = NULL;
    }
}

/*
 * Read the global buffer (the samples of the running or last measurement) and keep it in the
 * handle: counts[2] = samples held (blade, vr); *first_index = the buffer's first blade sample as
 * an index since hdeem_start (1-based, as the library reports first_blade_value).
 */
int hws_global_fetch(void *handle, long long *counts, long long *first_index) {
    hws_t *h = handle;
    global_release(h);
    hdeem_global_reading_t *g = calloc(1, sizeof(hdeem_global_reading_t));
    if (!g) return -12;
    int rc = hdeem_get_global(&h->bmc, g);
    if (rc != 0) {
        hdeem_data_free(g);   /* pointers are NULL or allocated even on error */
        free(g);
        return rc;
    }
    h->global = g;
    counts[0] = (long long)g->nb_blade_values;
    counts[1] = (long long)g->nb_vr_values;
    *first_index = (long long)g->first_blade_value;
    return 0;
}

/*
 * Copy samples [from, from + count) of sensor `sensor` (blade first) of the kept global reading into
 * out; returns the number copied or a negative code.
 */
long long hws_global_copy(void *handle, int sensor, long long from, long long count, double *out) {
    hws_t *h = handle;
    hdeem_global_reading_t *g = h->global;
    if (!g) return -1;
    int nb = h->bmc.nb_blade_sensors;
    int blade = sensor < nb;
    int s = blade ? sensor : sensor - nb;
    long long total = blade ? (long long)g->nb_blade_values : (long long)g->nb_vr_values;
    if (from < 0) from = 0;
    if (from + count > total) count = total - from;
    if (count < 0) count = 0;
    for (long long i = 0; i < count; i++)
        out[i] = blade ? g->blade_power[from + i].value[s] : g->vr_power[from + i].value[s];
    return count;
}
#else
static void global_release(hws_t *h) { (void)h; }
#endif
