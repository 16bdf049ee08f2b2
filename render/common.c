/* common.c — status table, method and component names, the render settings' defaults,
 * stage timings and the clock: small things every module uses. */
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "nscatter.h"

typedef struct {
    int value;
    const char *name;
    const char *message;
    int http;
} status_row;

static const status_row status_rows[] = {
#define NS_X_ROW(code, value, name, message, http) {value, name, message, http},
    NS_STATUS_TABLE(NS_X_ROW)
#undef NS_X_ROW
};

static const status_row *find_status(int status)
{
    for (size_t i = 0; i < sizeof status_rows / sizeof status_rows[0]; i++)
        if (status_rows[i].value == status)
            return &status_rows[i];
    return NULL;
}

const char *ns_status_name(int status)
{
    const status_row *row = find_status(status);
    return row ? row->name : "unknown";
}

const char *ns_status_message(int status)
{
    const status_row *row = find_status(status);
    return row ? row->message : "unknown status";
}

int ns_status_http(int status)
{
    const status_row *row = find_status(status);
    return row ? row->http : 500;
}

void ns_stats_add_stage(ns_render_stats *stats, const char *name, double ms)
{
    if (!stats)
        return;
    /* A stage that runs more than once (per sample batch, per medium) adds up. */
    for (uint32_t i = 0; i < stats->stage_count; i++)
        if (strncmp(stats->stages[i].name, name, sizeof stats->stages[i].name) == 0) {
            stats->stages[i].ms += ms;
            return;
        }
    if (stats->stage_count >= NS_MAX_STAGES)
        return;
    ns_stage_time *stage = &stats->stages[stats->stage_count++];
    snprintf(stage->name, sizeof stage->name, "%s", name);
    stage->ms = ms;
}

double ns_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

uint32_t ns_unsupported_components(ns_method method, uint32_t components)
{
    /* Every method renders every component, except the dipole: its diffusion profile holds
     * double and multiple scattering together and cannot give one without the other. */
    uint32_t gathered = NS_COMPONENT_DOUBLE | NS_COMPONENT_MULTIPLE;
    if (method == NS_METHOD_DIPOLE && (components & gathered) && (components & gathered) != gathered)
        return components & gathered;
    return 0;
}

ns_render_settings ns_render_settings_resolve(ns_render_settings r)
{
    /* The fields whose default is 0 need nothing; seed, gather_tolerance and single_tolerance
     * keep their 0, a value of its own there (nscatter.h). The others: 0 is outside their
     * range, so it can only mean "not set". */
    if (!r.components)
        r.components = NS_DEFAULT_COMPONENTS;
    if (!r.spp)
        r.spp = NS_DEFAULT_SPP;
    if (!r.max_depth)
        r.max_depth = NS_DEFAULT_MAX_DEPTH;
    if (!r.light_samples)
        r.light_samples = NS_DEFAULT_LIGHT_SAMPLES;
    if (!r.vrls)
        r.vrls = NS_DEFAULT_VRLS;
    if (!r.gather_tile)
        r.gather_tile = NS_DEFAULT_GATHER_TILE;
    if (!r.single_samples)
        r.single_samples = NS_DEFAULT_SINGLE_SAMPLES;
    return r;
}

int ns_adaptive_spp_applies(ns_method method, uint32_t spp)
{
    return method != NS_METHOD_PT && spp >= 2;
}

int ns_adaptive_spp_refused(ns_method method, uint32_t spp, float adaptive_spp)
{
    return adaptive_spp > 0.0f && method != NS_METHOD_PT && !ns_adaptive_spp_applies(method, spp);
}

float ns_adaptive_spp_used(const ns_render_settings *r)
{
    int used = ns_adaptive_spp_applies(r->method, r->spp) && (r->components & NS_COMPONENT_SURFACE);
    return used ? r->adaptive_spp : 0.0f;
}

static const char *const method_names[NS_METHOD_COUNT] = {
#define NS_X_NAME(code, value, name) [value] = name,
    NS_METHODS(NS_X_NAME)
};
static const char *const component_names[NS_COMPONENT_COUNT] = {
    NS_COMPONENTS(NS_X_NAME)
#undef NS_X_NAME
};

int ns_method_uses_tables(ns_method method)
{
    return method == NS_METHOD_NN || method == NS_METHOD_TABLE;
}

ns_boundary ns_default_boundary(ns_method method)
{
    return ns_method_uses_tables(method) ? NS_BOUNDARY_WALKS : NS_BOUNDARY_OFF;
}

const char *ns_boundary_name(ns_boundary boundary)
{
    return boundary == NS_BOUNDARY_OFF ? "off" : boundary == NS_BOUNDARY_WALKS ? "walks" : "unknown";
}

const char *ns_tables_name(ns_tables_mode tables)
{
    return tables == NS_TABLES_EXACT          ? "exact"
           : tables == NS_TABLES_INTERPOLATED ? "interpolated"
           : tables == NS_TABLES_AUTO         ? "auto"
                                              : "unknown";
}

const char *ns_method_name(ns_method method)
{
    return (unsigned)method < NS_METHOD_COUNT ? method_names[method] : "unknown";
}

int ns_method_parse(const char *name, ns_method *out)
{
    for (int m = 0; name && m < NS_METHOD_COUNT; m++)
        if (!strcmp(name, method_names[m])) {
            *out = (ns_method)m;
            return NS_OK;
        }
    return NS_ERR_INVALID_ARGUMENT;
}

const char *ns_component_name(uint32_t component)
{
    for (int bit = 0; bit < NS_COMPONENT_COUNT; bit++)
        if (component == 1u << bit)
            return component_names[bit];
    return "unknown";
}

int ns_component_parse(const char *name, uint32_t *out)
{
    for (int bit = 0; name && bit < NS_COMPONENT_COUNT; bit++)
        if (!strcmp(name, component_names[bit])) {
            *out = 1u << bit;
            return NS_OK;
        }
    return NS_ERR_INVALID_ARGUMENT;
}
