/* http.h — the HTTP render service (libmicrohttpd; docs/http.md): the one entry point of
 * server/, used by `nscatter serve` (cli/cmd_serve.c). */
#ifndef NS_HTTP_H
#define NS_HTTP_H

#include <stdint.h>

#define HTTP_DEFAULT_MAX_BODY (64ull * 1024 * 1024)
#define HTTP_DEFAULT_QUEUE 4u
#define HTTP_DEFAULT_SSE_KEEPALIVE_S 15u
#define HTTP_DEFAULT_REQUEST_TIMEOUT_S 30u
#define HTTP_DEFAULT_IDLE_TIMEOUT_S 60u
#define HTTP_DEFAULT_MAX_CONNECTIONS 512u

/* Zero means "default" in every field but port (0 picks a free port). */
typedef struct http_serve_desc {
    const char *host;      /* address or name to listen on; NULL: 127.0.0.1 */
    unsigned port;         /* TCP port; 0: a free one (printed) */
    uint32_t queue;        /* renders admitted at once, the running one included; 0: 4 */
    uint64_t max_body;     /* largest request body in bytes; 0: 64 MiB */
    const char *asset_dir; /* folder of mesh assets scenes may name; NULL: none */
    const char *device;    /* Vulkan device, index or name part; NULL: NSCATTER_DEVICE, lavapipe */
    uint32_t job_ttl_s;    /* finished asynchronous jobs are kept this long; 0: 3600 */
    uint64_t job_bytes;    /* results of jobs kept at most; 0: 1 GiB */
    uint32_t sse_keepalive_s; /* a quiet event stream gets a comment this often; 0: 15 */
    int no_access_log;        /* 1: no JSON line per request on stderr */
    uint32_t max_deadline_ms; /* cap on render.deadline_ms, and the deadline of a render that
                                 names none; 0: none */
    const char *instance;     /* 1-16 of [a-z0-9]: the prefix of job ids; NULL: none */
    /* Limits of a render below the hard ones (docs/http.md); 0: the hard one. */
    uint32_t max_pixels, max_spp, max_vrls, max_triangles;
    /* Slow and idle clients (docs/http.md, "Slow and idle clients"); 0: the default. */
    uint32_t request_timeout_s; /* a request's headers and body must arrive within it: 30 */
    uint32_t idle_timeout_s;    /* a connection silent this long is closed: 60 */
    uint32_t max_connections;   /* open at once (one thread each): 512 */
    int no_idle_work;           /* 1: no work between renders (job_store_desc) */
    /* 1: make no render context (no Vulkan at all): the service answers as it does when its
     * device could not be made (/readyz, renders and sweeps 503 no_device; validation, info
     * and the rest as usual). For the HTTP fuzz target (tests/fuzz_http.c), which needs the
     * request path, not a device. */
    int no_device;
} http_serve_desc;

/* Makes the render context, opens the socket, prints `listening on http://HOST:PORT` on
 * stdout and serves until SIGINT or SIGTERM, then drains admitted renders and returns the
 * process exit status: 0 stopped cleanly, 1 could not listen, 2 bad host. It is
 * http_start, a wait for a stop signal, and http_stop. */
int http_serve(const http_serve_desc *desc);

/* The same service for a program that serves in-process (tests/fuzz_http.c): no signal
 * handling, no output but errors on stderr. http_start makes the context and starts
 * listening on *port (the bound one when desc->port is 0); returns 0 and *svc, or the
 * status http_serve would exit with. http_stop drains as http_serve does after a signal and
 * frees everything. The caller ignores SIGPIPE (a client that disconnects must not kill
 * the process). */
typedef struct http_service http_service;
int http_start(const http_serve_desc *desc, http_service **svc, unsigned *port);
void http_stop(http_service *svc);
/* Connections open now, counted until each is closed and its request's memory freed (the
 * fuzz target waits for 0 between inputs, so that one input's work never runs into the
 * next's). */
unsigned http_connections(const http_service *svc);

#endif
