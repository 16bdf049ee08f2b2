/* fuzz_http.c — libFuzzer target for the HTTP request path: request line, headers, query
 * strings and body framing (Content-Length, chunked, pipelining) as libmicrohttpd and
 * server/http.c read them. Built only with -DNS_FUZZ=ON and clang; run by scripts/fuzz.sh
 * (docs/development.md, "Fuzzing").
 *
 * The real server runs in this process, started once with http_start() on a free loopback
 * port, and every input is one TCP connection: the bytes are sent as they are, the
 * connection is half-closed, and the answer is read to the end. The server is started
 * without a render device (http_serve_desc.no_device): renders on lavapipe would take
 * seconds per input, while every byte of the request path up to the render — routing,
 * headers, queries, the body's framing and limit, the scene parser behind
 * POST /v1/renders/validate — is the code `nscatter serve` runs. Render and sweep posts
 * answer 503 no_device, as a service whose device could not be made does.
 *
 * Besides ASan, UBSan and LeakSanitizer, every input must give an answer that parses as
 * a sequence of HTTP/1.1 responses (status line, headers, a body framed by its
 * Content-Length or chunks) with no 5xx from nscatter other than 503 (libmicrohttpd's own
 * refusals of what it cannot parse, 505 for HTTP/9.9 and the like, are told apart by their
 * lack of X-Request-Id: check_answer), and the server must close the connection after the
 * client's end of file within a few seconds. */
#define _GNU_SOURCE /* memmem */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "http.h"

int LLVMFuzzerInitialize(int *argc, char ***argv);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Small, so that bodies over the limit (declared or chunked) are within the fuzzer's reach. */
#define FUZZ_MAX_BODY 4096u
/* How long the server may take to answer and close after the client's end of file. A
 * loaded 2-core machine running ASan needs well under one second for any input. */
#define FUZZ_ANSWER_S 5.0
#define FUZZ_ANSWER_MAX (1u << 20)

static const char *header_value(const char *h, const char *end, const char *name, size_t *vlen);

static http_service *service;
static unsigned service_port;
/* What the inputs got, printed at exit: shows which parts of the path a run reached (a
 * run whose every answer is libmicrohttpd's 400 never reached nscatter's code). */
static unsigned long answers_by_class[6], answers_mhd, answers_none, answers_204;

static void stop_service(void)
{
    fprintf(stderr,
            "fuzz_http: first answers: none %lu, libmicrohttpd's own %lu, nscatter's 1xx %lu, "
            "2xx %lu (204 %lu), 3xx %lu, 4xx %lu, 503 %lu\n",
            answers_none, answers_mhd, answers_by_class[1], answers_by_class[2], answers_204,
            answers_by_class[3], answers_by_class[4], answers_by_class[5]);
    http_stop(service);
    service = NULL;
}

/* Counts the first response of an answer checked by check_answer. */
static void count_answer(const char *a, size_t len)
{
    if (len < 13) {
        answers_none++;
        return;
    }
    int status = (a[9] - '0') * 100 + (a[10] - '0') * 10 + (a[11] - '0');
    const char *head_end = memmem(a, len, "\r\n\r\n", 4);
    size_t vlen;
    if (!head_end || !header_value(a, head_end, "X-Request-Id", &vlen))
        answers_mhd++;
    else
        answers_by_class[status / 100]++;
    answers_204 += status == 204;
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    signal(SIGPIPE, SIG_IGN); /* the server writes to clients that may be gone */
    /* libFuzzer's watchdog is a SIGALRM every few seconds, which `nscatter serve` never
     * gets: the server's threads (they inherit this mask) leave it to this one. */
    sigset_t alarm_only;
    sigemptyset(&alarm_only);
    sigaddset(&alarm_only, SIGALRM);
    pthread_sigmask(SIG_BLOCK, &alarm_only, NULL);
    http_serve_desc desc = {.host = "127.0.0.1",
                            .port = 0,
                            .max_body = FUZZ_MAX_BODY,
                            .no_device = 1,
                            .no_access_log = 1};
    int rc = http_start(&desc, &service, &service_port);
    pthread_sigmask(SIG_UNBLOCK, &alarm_only, NULL);
    if (rc) {
        fprintf(stderr, "fuzz_http: the server did not start\n");
        exit(1);
    }
    atexit(stop_service);
    return 0;
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + t.tv_nsec * 1e-9;
}

static _Noreturn void fail(const char *why, const char *answer, size_t len)
{
    fprintf(stderr, "fuzz_http: %s\n--- answer (%zu bytes) ---\n%.*s\n---\n", why, len,
            (int)(len < 2000 ? len : 2000), answer ? answer : "");
    abort();
}

/* The value of header `name` in the header block [h, end), or NULL. */
static const char *header_value(const char *h, const char *end, const char *name, size_t *vlen)
{
    size_t n = strlen(name);
    for (const char *line = h; line < end;) {
        const char *eol = memchr(line, '\n', (size_t)(end - line));
        if (!eol)
            eol = end;
        if ((size_t)(eol - line) > n && line[n] == ':' && !strncasecmp(line, name, n)) {
            const char *v = line + n + 1;
            while (v < eol && *v == ' ')
                v++;
            const char *ve = eol;
            while (ve > v && (ve[-1] == '\r' || ve[-1] == ' '))
                ve--;
            *vlen = (size_t)(ve - v);
            return v;
        }
        line = eol + 1;
    }
    return NULL;
}

/* Skips a chunked body at p; returns its end, or NULL when the chunks are cut short. */
static const char *skip_chunks(const char *p, const char *end)
{
    for (;;) {
        char *after = NULL;
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            return NULL;
        unsigned long long n = strtoull(p, &after, 16);
        if (after == p)
            return NULL;
        p = eol + 1;
        if (n == 0) { /* trailers, then an empty line */
            for (;;) {
                eol = memchr(p, '\n', (size_t)(end - p));
                if (!eol)
                    return NULL;
                int empty = eol == p || (eol == p + 1 && *p == '\r');
                p = eol + 1;
                if (empty)
                    return p;
            }
        }
        if (n > (unsigned long long)(end - p))
            return NULL;
        p += n;
        if (end - p >= 2 && p[0] == '\r' && p[1] == '\n')
            p += 2;
        else
            return NULL;
    }
}

/* The answer must be whole HTTP/1.1 responses, one after another; only the last may be cut
 * short (the server closes a connection whose next request broke off). */
static void check_answer(const char *a, size_t len)
{
    const char *p = a, *end = a + len;
    while (p < end) {
        const char *start = p;
        if (end - p < 13 || memcmp(p, "HTTP/1.1 ", 9) ||
            !(p[9] >= '1' && p[9] <= '5' && p[10] >= '0' && p[10] <= '9' && p[11] >= '0' &&
              p[11] <= '9' && p[12] == ' '))
            fail("not an HTTP/1.1 status line", a, len);
        int status = (p[9] - '0') * 100 + (p[10] - '0') * 10 + (p[11] - '0');
        const char *head_end = NULL;
        for (const char *q = p; q + 3 < end; q++)
            if (!memcmp(q, "\r\n\r\n", 4)) {
                head_end = q + 4;
                break;
            }
        if (!head_end)
            fail("a response's headers never end", a, len);
        p = head_end;
        size_t vlen = 0;
        /* Every answer of server/http.c carries X-Request-Id; those without are
         * libmicrohttpd's own, sent before the request reaches nscatter: 100 Continue and
         * its refusals of a request it cannot parse (400, 413, 414, 431, 501 for a
         * transfer coding it does not implement, 505 for an HTTP version it does not
         * speak). A server fault (500, 502, 504...) is never a right answer. */
        if (header_value(start, head_end, "X-Request-Id", &vlen)) {
            if (status >= 500 && status != 503)
                fail("nscatter answered a 5xx other than 503", a, len);
        } else if (!(status == 100 || status == 400 || status == 413 || status == 414 ||
                     status == 431 || status == 501 || status == 505)) {
            fail("libmicrohttpd answered a status outside its refusals", a, len);
        }
        if (status < 200 || status == 204 || status == 304)
            continue; /* no body */
        const char *te = header_value(start, head_end, "Transfer-Encoding", &vlen);
        if (te && vlen == 7 && !strncasecmp(te, "chunked", 7)) {
            p = skip_chunks(p, end);
            if (!p)
                return; /* cut short: only the last response may be */
            continue;
        }
        const char *cl = header_value(start, head_end, "Content-Length", &vlen);
        if (!cl)
            return; /* a body up to the end of the connection */
        unsigned long long n = strtoull(cl, NULL, 10);
        /* A HEAD answer has the length of the body it leaves out: when the next response
         * starts right here, this one had none. */
        if (n > 0 && end - p >= 9 && !memcmp(p, "HTTP/1.1 ", 9))
            continue;
        if (n > (unsigned long long)(end - p))
            return;
        p += n;
    }
}

/* Sends everything it can (the server may close early: a refused body is not read). */
static void send_all(int fd, const uint8_t *data, size_t size, double deadline)
{
    size_t sent = 0;
    while (sent < size && now_s() < deadline) {
        ssize_t n = send(fd, data + sent, size - sent, MSG_NOSIGNAL);
        if (n > 0)
            sent += (size_t)n;
        else if (n < 0 && errno == EINTR)
            continue;
        else
            return;
    }
}

/* A connection to the server. libFuzzer's SIGALRM (its -timeout watchdog, every few
 * seconds, installed without SA_RESTART) may interrupt connect(): the connection then goes
 * on in the background, and its outcome is read once the socket is writable. */
static int connect_to_service(void)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        perror("fuzz_http: socket");
        abort();
    }
    struct sockaddr_in addr = {.sin_family = AF_INET, .sin_port = htons((uint16_t)service_port)};
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    int err = connect(fd, (struct sockaddr *)&addr, sizeof addr) ? errno : 0;
    if (err == EINTR || err == EINPROGRESS) {
        struct pollfd pfd = {.fd = fd, .events = POLLOUT};
        double until = now_s() + FUZZ_ANSWER_S;
        int r = 0;
        while (now_s() < until && (r = poll(&pfd, 1, 100)) <= 0)
            ;
        socklen_t len = sizeof err;
        if (r <= 0 || getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len))
            err = ETIMEDOUT;
    }
    if (err) {
        fprintf(stderr, "fuzz_http: connect: %s\n", strerror(err));
        fail("cannot connect: the server is gone", NULL, 0);
    }
    return fd;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int fd = connect_to_service();
    struct timeval tv = {.tv_sec = 1};
    setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    double deadline = now_s() + FUZZ_ANSWER_S;
    send_all(fd, data, size, deadline);
    shutdown(fd, SHUT_WR);

    char *answer = malloc(FUZZ_ANSWER_MAX);
    size_t len = 0;
    int closed = 0;
    while (!closed && answer) {
        double left = deadline - now_s();
        if (left <= 0)
            break;
        struct pollfd pfd = {.fd = fd, .events = POLLIN};
        int r = poll(&pfd, 1, (int)(left * 1000) + 1);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            break;
        char scratch[4096];
        char *into = len < FUZZ_ANSWER_MAX ? answer + len : scratch;
        size_t room = len < FUZZ_ANSWER_MAX ? FUZZ_ANSWER_MAX - len : sizeof scratch;
        ssize_t n = recv(fd, into, room, 0);
        if (n > 0 && into == answer + len)
            len += (size_t)n;
        else if (n == 0 || (n < 0 && errno != EINTR))
            closed = 1; /* end of file, or a reset after a refused body */
    }
    close(fd);
    if (!closed)
        fail("the server neither closed the connection nor stopped answering in time", answer, len);
    check_answer(answer, len);
    count_answer(answer, len);
    free(answer);
    /* The connection's thread ends after its socket closes: wait for it, so that this
     * input's work (the completion callback, the access log's bookkeeping) is over before
     * the next input starts and before LeakSanitizer looks. */
    double wait_until = now_s() + FUZZ_ANSWER_S;
    while (http_connections(service) > 0) {
        if (now_s() > wait_until)
            fail("a connection stayed open after its client left", NULL, 0);
        struct timespec nap = {.tv_nsec = 100000};
        nanosleep(&nap, NULL);
    }
    return 0;
}
