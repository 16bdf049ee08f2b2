/* unit_problem.c — the service's problem table (server/problem.h): every kind has a status,
 * a title and (but for the render-status rows) a code of its own; the render library's
 * statuses map onto rows of their own HTTP status; and a problem's JSON carries exactly the
 * table's values. The http_* tests check the same answers on the wire. */
#include <stdlib.h>
#include <string.h>

#include "harness.h"
#include "nscatter.h"
#include "problem.h"

/* Every render status, from nscatter.h's table, so a status added there is tested too. */
static const int statuses[] = {
#define STATUS_X(code, value, name, message, http) code,
    NS_STATUS_TABLE(STATUS_X)
#undef STATUS_X
};
#define STATUS_COUNT (sizeof statuses / sizeof statuses[0])

static void test_table_columns(void)
{
    for (int k = 0; k < PROBLEM_COUNT; k++) {
        int status = problem_http_status((problem_kind)k);
        CHECK(status >= 400 && status < 600);
        const char *title = problem_title((problem_kind)k);
        CHECK(title && *title);
        /* Two kinds with one status share its reason phrase. */
        for (int j = 0; j < k; j++)
            if (problem_http_status((problem_kind)j) == status)
                CHECK(!strcmp(problem_title((problem_kind)j), title));
        const char *code = problem_code((problem_kind)k);
        if (!code)
            continue;
        for (const char *c = code; *c; c++)
            CHECK((*c >= 'a' && *c <= 'z') || *c == '_');
        /* A service code never collides with a render status name: a client could not tell
         * which one it got. */
        for (size_t s = 0; s < STATUS_COUNT; s++)
            CHECK(strcmp(code, ns_status_name(statuses[s])) != 0);
        for (int j = 0; j < k; j++)
            CHECK(!problem_code((problem_kind)j) || strcmp(problem_code((problem_kind)j), code));
    }
    CHECK_INT(problem_http_status(PROBLEM_NOT_FOUND), 404);
    CHECK(!strcmp(problem_code(PROBLEM_BODY_TOO_LARGE), "body_too_large"));
    CHECK(!strcmp(problem_title(PROBLEM_BODY_TOO_LARGE), "Content Too Large"));
    CHECK(problem_code(PROBLEM_STATUS_INTERNAL) == NULL);
    /* Outside the enum: the internal-error row, never an out-of-bounds read. */
    CHECK_INT(problem_http_status((problem_kind)-1), 500);
    CHECK_INT(problem_http_status(PROBLEM_COUNT), 500);
}

/* Every render status but NS_OK has a row with its HTTP status: a status added to
 * nscatter.h with a new HTTP status fails here until the table has a row (and title) for it. */
static void test_every_status_has_a_row(void)
{
    for (size_t s = 0; s < STATUS_COUNT; s++) {
        if (statuses[s] == NS_OK)
            continue;
        problem_kind k = problem_kind_of_status(statuses[s]);
        CHECK(problem_code(k) == NULL);
        CHECK_INT(problem_http_status(k), ns_status_http(statuses[s]));
    }
    CHECK_INT(problem_kind_of_status(NS_ERR_NOT_AVAILABLE), PROBLEM_STATUS_UNPROCESSABLE);
    CHECK_INT(problem_kind_of_status(NS_ERR_DEVICE_LOST), PROBLEM_STATUS_INTERNAL);
    CHECK_INT(problem_kind_of_status(NS_ERR_OUT_OF_HOST_MEMORY), PROBLEM_STATUS_UNAVAILABLE);
    CHECK_INT(problem_kind_of_status(12345), PROBLEM_STATUS_INTERNAL); /* not a status */
}

static const char *get_string(const json_t *p, const char *key)
{
    return json_string_value(json_object_get(p, key));
}

static void test_problem_json(void)
{
    json_t *p = problem_new(PROBLEM_METHOD_NOT_ALLOWED, "PUT is not allowed on /livez; use GET");
    CHECK(p != NULL);
    CHECK(!strcmp(get_string(p, "type"), "urn:nscatter:problem:method_not_allowed"));
    CHECK(!strcmp(get_string(p, "title"), "Method Not Allowed"));
    CHECK_INT(json_integer_value(json_object_get(p, "status")), 405);
    CHECK(!strcmp(get_string(p, "code"), "method_not_allowed"));
    CHECK(!strcmp(get_string(p, "detail"), "PUT is not allowed on /livez; use GET"));
    CHECK(json_is_array(json_object_get(p, "errors")) &&
          json_array_size(json_object_get(p, "errors")) == 0);
    CHECK_INT(json_object_size(p), 6);
    problem_add_error(p, "/camera/fov", "must be in (0, 180)");
    json_t *e = json_array_get(json_object_get(p, "errors"), 0);
    CHECK(e && !strcmp(get_string(e, "pointer"), "/camera/fov"));
    json_decref(p);

    /* A detail that is not UTF-8 (a client's bytes quoted back) still makes a problem. */
    p = problem_new(PROBLEM_BAD_QUERY, "unknown query parameter '\xff\xfe'");
    CHECK(p && !strcmp(get_string(p, "detail"), "unknown query parameter '?\?'"));
    json_decref(p);
    p = problem_new(PROBLEM_NOT_FOUND, NULL);
    CHECK(p && !strcmp(get_string(p, "detail"), ""));
    json_decref(p);
}

static void test_status_problems(void)
{
    /* A render failure: the status's name, its HTTP status and that status's title. */
    json_t *p =
        problem_from_status(problem_kind_of_status(NS_ERR_DEVICE_LOST), NS_ERR_DEVICE_LOST, "lost");
    CHECK(!strcmp(get_string(p, "code"), "device_lost"));
    CHECK(!strcmp(get_string(p, "type"), "urn:nscatter:problem:device_lost"));
    CHECK_INT(json_integer_value(json_object_get(p, "status")), 500);
    CHECK(!strcmp(get_string(p, "title"), "Internal Server Error"));
    json_decref(p);
    /* /readyz: 503 whatever the status's own HTTP status (no_device's is 500). */
    p = problem_from_status(PROBLEM_STATUS_UNAVAILABLE, NS_ERR_NO_DEVICE, "no device");
    CHECK(!strcmp(get_string(p, "code"), "no_device"));
    CHECK_INT(json_integer_value(json_object_get(p, "status")), 503);
    CHECK(!strcmp(get_string(p, "title"), "Service Unavailable"));
    json_decref(p);
    /* A render-status row given to problem_new has no code of its own: internal_error. */
    p = problem_new(PROBLEM_STATUS_INTERNAL, "x");
    CHECK(!strcmp(get_string(p, "code"), "internal_error"));
    json_decref(p);
}

int main(void)
{
    RUN(test_table_columns);
    RUN(test_every_status_has_a_row);
    RUN(test_problem_json);
    RUN(test_status_problems);
    return harness_report();
}
