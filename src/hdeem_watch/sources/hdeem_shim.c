/*
 * hdeem-watch's shim over libhdeem: flat C functions with plain types, loaded with ctypes.
 *
 * The exact C types and layouts of hdeem.h are not public. EVERY assumption about them is in this
 * file, which is compiled on the node against the installed hdeem.h:
 *   cc -shared -fPIC -O2 hdeem_shim.c -I<include> -L<lib> -lhdeem -lfreeipmi -lrt -o libhdeem_shim.so
 * Assumed (from the documented API): the functions hdeem_init/close/start/stop/clear/check_status/
 * get_stats/get_stats_total/stats_free/get_global/data_free, all returning int 0 on success; the
 * fields bmc.{host,user,password,nb_blade_sensors,nb_vr_sensors,name_blade_sensors[i],
 * name_vr_sensors[i]}; stats.{max,min,average,instant}_{blade,vr}_values.value[s] (W),
 * stats.energy_{blade,vr}_values.value[s] (J), stats.nb_{blade,vr}_values, stats.read_time_{blade,vr}
 * (struct timespec); global.nb_{blade,vr}_values, global.{blade,vr}_power[i].value[s],
 * global.first_blade_value (struct timespec); bmc.hasGPIO/hasPCIe (1 for in-band, 0 for
 * out-of-band; build with -DHWS_NO_GPIO_FIELDS if the header lacks them); the status macros
 * IsBmcPolling, IsFpgaPolling, IsBmcOverflow, IsFpgaBladeOverflow, IsFpgaVrOverflow taking the int
 * status word status.status; hdeem_data_free() is safe (and needed) after a failed get_global.
 *
 * Sensors are numbered blade sensors first, then VR sensors. Times are wall-clock ns.
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

typedef struct {
    hdeem_bmc_data_t bmc;
    hdeem_global_reading_t global;
    int have_global;
    char *host, *user, *password;
} hws_t;

static long long ts_ns(struct timespec ts) { return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec; }

static char *dup_or_null(const char *s) { return (s && *s) ? strdup(s) : NULL; }

int hws_abi_version(void) { return 1; }

/* Connect; returns a handle, or NULL with *err = hdeem_init's code (or -12 out of memory). */
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

int hws_close(void *handle) {
    hws_t *h = handle;
    if (!h) return 0;
    if (h->have_global) hdeem_data_free(&h->global);
    int rc = hdeem_close(&h->bmc);
    free(h->host);
    free(h->user);
    free(h->password);
    free(h);
    return rc;
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
    if (len <= 0) return -1;
    if (index < 0) return -1;
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

int hws_status(void *handle, int *flags) {
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
    if (rc != 0) return rc;
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

/* Read the global buffer (all samples since start) and keep it; counts[2], *first_ns. */
int hws_global_fetch(void *handle, long long *counts, long long *first_ns) {
    hws_t *h = handle;
    if (h->have_global) {
        hdeem_data_free(&h->global);
        h->have_global = 0;
    }
    memset(&h->global, 0, sizeof(h->global));
    int rc = hdeem_get_global(&h->bmc, &h->global);
    if (rc != 0) {
        hdeem_data_free(&h->global);   /* pointers are NULL or allocated even on error */
        return rc;
    }
    h->have_global = 1;
    counts[0] = (long long)h->global.nb_blade_values;
    counts[1] = (long long)h->global.nb_vr_values;
    *first_ns = ts_ns(h->global.first_blade_value);
    return 0;
}

/*
 * Copy samples [from, from + count) of sensor `sensor` (blade first) of the kept global reading into
 * out; returns the number copied or a negative code.
 */
long long hws_global_copy(void *handle, int sensor, long long from, long long count, double *out) {
    hws_t *h = handle;
    if (!h->have_global) return -1;
    int nb = h->bmc.nb_blade_sensors;
    int blade = sensor < nb;
    int s = blade ? sensor : sensor - nb;
    long long total = blade ? (long long)h->global.nb_blade_values : (long long)h->global.nb_vr_values;
    if (from < 0) from = 0;
    if (from + count > total) count = total - from;
    if (count < 0) count = 0;
    for (long long i = 0; i < count; i++)
        out[i] = blade ? h->global.blade_power[from + i].value[s] : h->global.vr_power[from + i].value[s];
    return count;
}
