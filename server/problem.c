/* problem.c — RFC 9457 problem details. */
#include "problem.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

const char *problem_title(int http_status)
{
    switch (http_status) {
    case 400:
        return "Bad Request";
    case 404:
        return "Not Found";
    case 405:
        return "Method Not Allowed";
    case 406:
        return "Not Acceptable";
    case 408:
        return "Request Timeout";
    case 413:
        return "Content Too Large";
    case 415:
        return "Unsupported Media Type";
    case 422:
        return "Unprocessable Content";
    case 500:
        return "Internal Server Error";
    case 503:
        return "Service Unavailable";
    default:
        return http_status >= 500 ? "Server Error" : "Client Error";
    }
}

json_t *problem_new(int http_status, const char *code, const char *detail)
{
    char type[128];
    snprintf(type, sizeof type, "urn:nscatter:problem:%s", code);
    return json_pack("{s:s, s:s, s:i, s:o, s:o, s:[]}", "type", type, "title",
                     problem_title(http_status), "status", http_status, "detail",
                     problem_string(detail), "code", problem_string(code), "errors");
}

void problem_add_error(json_t *problem, const char *pointer, const char *detail)
{
    json_t *errors = json_object_get(problem, "errors");
    if (json_is_array(errors))
        json_array_append_new(errors, json_pack("{s:o, s:o}", "pointer", problem_string(pointer),
                                                "detail", problem_string(detail)));
}
