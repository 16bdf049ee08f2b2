/* cmd_serve.c — `nscatter serve`: the command line of the HTTP service (server/include/http.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "args.h"
#include "commands.h"
#include "http.h"
#include "nscatter.h"

static void serve_usage(FILE *out)
{
    fprintf(out,
            "usage: nscatter serve [options]\n"
            "\n"
            "  --host ADDR       address to listen on (default 127.0.0.1)\n"
            "  --port N          TCP port (default 8080); 0 picks a free one\n"
            "  --queue N         renders admitted at once, running one included (default 4);\n"
            "                    more get 503 with Retry-After\n"
            "  --max-body BYTES  largest request body (default 67108864 = 64 MiB)\n"
            "  --assets DIR      folder of mesh assets scenes may name (\"asset\": \"x.glb\")\n"
            "  --device D        Vulkan device: index or name substring (default: lavapipe;\n"
            "                    also NSCATTER_DEVICE)\n"
            "  --job-ttl S       keep finished asynchronous renders and sweeps S seconds\n"
            "                    (default 3600); then they answer 410\n"
            "  --job-bytes BYTES keep at most this much of their results (default 1073741824);\n"
            "                    the oldest finished job goes first\n"
            "  --access-log on|off  one JSON line per request on stderr (default on)\n"
            "  --idle-work on|off   between renders, make the albedo nodes of a material whose\n"
            "                    albedo is being swept, so its next albedos blend their\n"
            "                    tables at once (default on; docs/http.md)\n"
            "  --max-pixels N, --max-spp N, --max-vrls N, --max-triangles N\n"
            "                    this service's limits of a render, below the hard ones\n"
            "  --instance NAME   prefix of job ids (NAME-<32 hex>), so a load balancer can\n"
            "                    route a job's requests to this instance (a-z, 0-9, 1-16)\n"
            "  --max-deadline-ms N  longest render.deadline_ms, and the deadline of renders\n"
            "                    that name none (default: none)\n"
            "  --sse-keepalive S comment on a quiet event stream every S seconds (1-50,\n"
            "                    default 15)\n"
            "  --request-timeout S  a request's headers and body must arrive within S\n"
            "                    seconds (plus 1 s per 64 KiB of body), else 408 (default 30)\n"
            "  --idle-timeout S  close a connection silent for S seconds (default 60)\n"
            "  --max-connections N  connections open at once, one thread each (default 512);\n"
            "                    near the limit, idle ones are closed first"
            "\n"
            "The first line on stdout is `listening on http://HOST:PORT` once the render\n"
            "context is ready and the socket is open. SIGINT/SIGTERM stop it cleanly.\n");
}

static int parse_serve_args(int argc, char **argv, http_serve_desc *a, int *done)
{
    *a = (http_serve_desc){.host = "127.0.0.1",
                      .port = 8080,
                      .queue = HTTP_DEFAULT_QUEUE,
                      .max_body = HTTP_DEFAULT_MAX_BODY};
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i], *value = i + 1 < argc ? argv[i + 1] : NULL;
        uint64_t n = 0;
        if (!strcmp(arg, "-h") || !strcmp(arg, "--help")) {
            serve_usage(stdout);
            *done = 1;
            return 0;
        }
        if (!value) {
            fprintf(stderr, "nscatter serve: unknown option or missing value: '%s'\n", arg);
            serve_usage(stderr);
            return 2;
        }
        i++;
        if (!strcmp(arg, "--host")) {
            a->host = value;
        } else if (!strcmp(arg, "--port")) {
            if (cli_parse_uint("nscatter serve", arg, value, 0, 65535, &n))
                return 2;
            a->port = (unsigned)n;
        } else if (!strcmp(arg, "--queue")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, 1024, &n))
                return 2;
            a->queue = (uint32_t)n;
        } else if (!strcmp(arg, "--max-body")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, 1ull << 32, &n))
                return 2;
            a->max_body = n;
        } else if (!strcmp(arg, "--assets")) {
            a->asset_dir = value;
        } else if (!strcmp(arg, "--device")) {
            a->device = value;
        } else if (!strcmp(arg, "--job-ttl")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, 30u * 24 * 3600, &n))
                return 2;
            a->job_ttl_s = (uint32_t)n;
        } else if (!strcmp(arg, "--job-bytes")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, 1ull << 40, &n))
                return 2;
            a->job_bytes = n;
        } else if (!strcmp(arg, "--max-pixels") || !strcmp(arg, "--max-spp") ||
                   !strcmp(arg, "--max-vrls") || !strcmp(arg, "--max-triangles")) {
            /* The service's own limits, at most the hard ones (render/include/nscatter.h). */
            const struct {
                const char *name;
                uint32_t hard;
                uint32_t *field;
            } limits[] = {{"--max-pixels", NS_MAX_PIXELS, &a->max_pixels},
                          {"--max-spp", NS_MAX_SPP, &a->max_spp},
                          {"--max-vrls", NS_MAX_VRLS, &a->max_vrls},
                          {"--max-triangles", NS_MAX_TRIANGLES, &a->max_triangles}};
            for (size_t k = 0; k < sizeof limits / sizeof limits[0]; k++)
                if (!strcmp(arg, limits[k].name)) {
                    if (cli_parse_uint("nscatter serve", arg, value, 1, limits[k].hard, &n))
                        return 2;
                    *limits[k].field = (uint32_t)n;
                }
        } else if (!strcmp(arg, "--instance")) {
            size_t len = strlen(value);
            if (len < 1 || len > 16 ||
                strspn(value, "abcdefghijklmnopqrstuvwxyz0123456789") != len) {
                fprintf(stderr, "nscatter serve: --instance: 1 to 16 of a-z and 0-9, got '%s'\n",
                        value);
                return 2;
            }
            a->instance = value;
        } else if (!strcmp(arg, "--max-deadline-ms")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, NS_MAX_DEADLINE_MS, &n))
                return 2;
            a->max_deadline_ms = (uint32_t)n;
        } else if (!strcmp(arg, "--idle-work") || !strcmp(arg, "--access-log")) {
            if (strcmp(value, "on") && strcmp(value, "off")) {
                fprintf(stderr, "nscatter serve: %s on|off, got '%s'\n", arg, value);
                return 2;
            }
            *(!strcmp(arg, "--idle-work") ? &a->no_idle_work : &a->no_access_log) = !strcmp(value, "off");
        } else if (!strcmp(arg, "--request-timeout") || !strcmp(arg, "--idle-timeout")) {
            if (cli_parse_uint("nscatter serve", arg, value, 1, 3600, &n))
                return 2;
            *(!strcmp(arg, "--request-timeout") ? &a->request_timeout_s : &a->idle_timeout_s) =
                (uint32_t)n;
        } else if (!strcmp(arg, "--max-connections")) {
            if (cli_parse_uint("nscatter serve", arg, value, 16, 4096, &n))
                return 2;
            a->max_connections = (uint32_t)n;
        } else if (!strcmp(arg, "--sse-keepalive")) {
            /* Below the 60 s after which a connection without traffic is closed. */
            if (cli_parse_uint("nscatter serve", arg, value, 1, 50, &n))
                return 2;
            a->sse_keepalive_s = (uint32_t)n;
        } else {
            fprintf(stderr, "nscatter serve: unknown option '%s'\n", arg);
            serve_usage(stderr);
            return 2;
        }
    }
    return 0;
}

int cmd_serve(int argc, char **argv)
{
    http_serve_desc desc;
    int done = 0;
    int rc = parse_serve_args(argc, argv, &desc, &done);
    if (rc || done)
        return rc;
    return http_serve(&desc);
}
