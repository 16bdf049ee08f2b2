/* problem.h — RFC 9457 problem details (application/problem+json) for HTTP errors.
 *
 *   {"type": "urn:nscatter:problem:<code>", "title": "Unprocessable Content", "status": 422,
 *    "detail": "...", "code": "<code>", "errors": [{"pointer": "/materials/wax/g",
 *    "detail": "..."}]}
 *
 * `code` is stable (a service code such as "malformed_json", or an ns_status name such as
 * "not_available"); clients branch on it, never on the wording of title or detail.
 */
#ifndef NS_PROBLEM_H
#define NS_PROBLEM_H

#include <jansson.h>

#define PROBLEM_CONTENT_TYPE "application/problem+json"

/* Every kind of problem the service answers with, in one table that generates the enum,
 * the codes, the titles and the HTTP statuses: X(NAME, status, "code", "Title").
 *
 * The PROBLEM_STATUS_* rows carry a failure of the render library: their code is NULL here
 * because it is the ns_status's own name (render/include/nscatter.h's status table), given to
 * problem_from_status(). There is one such row per HTTP status that table maps to, so that
 * each has its title here too; docs/http.md lists them all. */
#define PROBLEM_TABLE(X)                                                                      \
    X(PROBLEM_BAD_QUERY, 400, "bad_query", "Bad Request")                                     \
    X(PROBLEM_MALFORMED_JSON, 400, "malformed_json", "Bad Request")                           \
    X(PROBLEM_BAD_FRAMING, 400, "bad_framing", "Bad Request")                                 \
    X(PROBLEM_NOT_FOUND, 404, "not_found", "Not Found")                                       \
    X(PROBLEM_METHOD_NOT_ALLOWED, 405, "method_not_allowed", "Method Not Allowed")            \
    X(PROBLEM_NOT_ACCEPTABLE, 406, "not_acceptable", "Not Acceptable")                        \
    X(PROBLEM_REQUEST_TIMEOUT, 408, "request_timeout", "Request Timeout")                     \
    X(PROBLEM_BODY_TOO_LARGE, 413, "body_too_large", "Content Too Large")                     \
    X(PROBLEM_UNSUPPORTED_MEDIA_TYPE, 415, "unsupported_media_type", "Unsupported Media Type") \
    X(PROBLEM_INVALID_SCENE, 422, "invalid_scene", "Unprocessable Content")                   \
    X(PROBLEM_QUEUE_FULL, 503, "queue_full", "Service Unavailable")                           \
    X(PROBLEM_TOO_MANY_STREAMS, 503, "too_many_streams", "Service Unavailable")               \
    X(PROBLEM_SHUTTING_DOWN, 503, "shutting_down", "Service Unavailable")                     \
    X(PROBLEM_JOB_NOT_DONE, 409, "job_not_done", "Conflict")                                  \
    X(PROBLEM_JOB_GONE, 410, "job_gone", "Gone")                                              \
    X(PROBLEM_INVALID_SWEEP, 422, "invalid_sweep", "Unprocessable Content")                   \
    X(PROBLEM_STATUS_CONFLICT, 409, NULL, "Conflict")                                         \
    X(PROBLEM_STATUS_UNPROCESSABLE, 422, NULL, "Unprocessable Content")                       \
    X(PROBLEM_STATUS_INTERNAL, 500, NULL, "Internal Server Error")                            \
    X(PROBLEM_STATUS_UNAVAILABLE, 503, NULL, "Service Unavailable")

typedef enum {
#define PROBLEM_X_ENUM(name, status, code, title) name,
    PROBLEM_TABLE(PROBLEM_X_ENUM)
#undef PROBLEM_X_ENUM
    PROBLEM_COUNT
} problem_kind;

/* The table's columns; a kind outside the enum reads as PROBLEM_STATUS_INTERNAL. */
int problem_http_status(problem_kind kind);
const char *problem_code(problem_kind kind); /* NULL for the PROBLEM_STATUS_* rows */
const char *problem_title(problem_kind kind);

/* New reference with an empty "errors" list; NULL only when out of memory. kind has a code
 * of its own; a PROBLEM_STATUS_* row given here reads as the status NS_ERR_INTERNAL (those
 * rows go through problem_from_status). */
json_t *problem_new(problem_kind kind, const char *detail);

/* A failure the render library reports with an ns_status, answered as `kind`, one of the
 * PROBLEM_STATUS_* rows: the status's name is the code. Most callers pass
 * problem_kind_of_status(status), the row of the HTTP status the status table gives;
 * /readyz passes PROBLEM_STATUS_UNAVAILABLE whatever kept the context from being made. */
json_t *problem_from_status(problem_kind kind, int status, const char *detail);

/* The PROBLEM_STATUS_* row whose HTTP status is ns_status_http(status); a status whose HTTP
 * status has no row reads as PROBLEM_STATUS_INTERNAL (tests/unit_problem.c checks that every
 * ns_status has its row). */
problem_kind problem_kind_of_status(int status);

/* Appends {"pointer": pointer, "detail": detail} to the problem's errors. */
void problem_add_error(json_t *problem, const char *pointer, const char *detail);

#endif
