/* problem.c — RFC 9457 problem details. */
#include "problem.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "nscatter.h"

typedef struct {
    int status;
    const char *code;
    const char *title;
} problem_row;

static const problem_row problem_rows[PROBLEM_COUNT] = {
#define PROBLEM_X_ROW(name, status, code, title) [name] = {status, code, title},
    PROBLEM_TABLE(PROBLEM_X_ROW)
#undef PROBLEM_X_ROW
};

static const problem_row *row_of(problem_kind kind)
{
    return (unsigned)kind < PROBLEM_COUNT ? &problem_rows[kind]
                                          : &problem_rows[PROBLEM_STATUS_INTERNAL];
}

int problem_http_status(problem_kind kind)
{
    return row_of(kind)->status;
}

const char *problem_code(problem_kind kind)
{
    return row_of(kind)->code;
}

const char *problem_title(problem_kind kind)
{
    return row_of(kind)->title;
}

problem_kind problem_kind_of_status(int status)
{
    int http = ns_status_http(status);
    for (int k = 0; k < PROBLEM_COUNT; k++)
        if (!problem_rows[k].code && problem_rows[k].status == http)
            return (problem_kind)k;
    return PROBLEM_STATUS_INTERNAL;
}

/* Details may quote what a client sent; a string that is not valid UTF-8 would make the
 * whole JSON body fail to build, so such bytes become '?' instead. */
static json_t *problem_string(const char *text)
{
    if (!text)
        text = "";
    json_t *s = json_string(text);
    if (s)
        return s;
    size_t n = strlen(text);
    char *ascii = malloc(n + 1);
    if (!ascii)
        return json_string("");
    for (size_t i = 0; i <= n; i++)
        ascii[i] = (unsigned char)text[i] >= 0x80 ? '?' : text[i];
    s = json_string(ascii);
    free(ascii);
    return s;
}

static json_t *problem_make(const problem_row *row, const char *code, const char *detail)
{
    char type[128];
    snprintf(type, sizeof type, "urn:nscatter:problem:%s", code);
    return json_pack("{s:s, s:s, s:i, s:o, s:o, s:[]}", "type", type, "title", row->title, "status",
                     row->status, "detail", problem_string(detail), "code", problem_string(code),
                     "errors");
}

json_t *problem_new(problem_kind kind, const char *detail)
{
    const problem_row *row = row_of(kind);
    if (!row->code)
        return problem_from_status(kind, NS_ERR_INTERNAL, detail);
    return problem_make(row, row->code, detail);
}

json_t *problem_from_status(problem_kind kind, int status, const char *detail)
{
    return problem_make(row_of(kind), ns_status_name(status), detail);
}

void problem_add_error(json_t *problem, const char *pointer, const char *detail)
{
    json_t *errors = json_object_get(problem, "errors");
    if (json_is_array(errors))
        json_array_append_new(errors, json_pack("{s:o, s:o}", "pointer", problem_string(pointer),
                                                "detail", problem_string(detail)));
}
