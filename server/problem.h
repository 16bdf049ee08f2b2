/* problem.h — RFC 9457 problem details (application/problem+json) for HTTP errors.
 *
 *   {"type": "urn:nscatter:problem:<code>", "title": "Unprocessable Content", "status": 422,
 *    "detail": "...", "code": "<code>", "errors": [{"pointer": "/materials/wax/g",
 *    "detail": "..."}]}
 *
 * `code` is stable (an ns_status name such as "not_available", or a service code such as
 * "malformed_json"); clients branch on it, never on the wording of title or detail.
 */
#ifndef NS_PROBLEM_H
#define NS_PROBLEM_H

#include <jansson.h>

#define PROBLEM_CONTENT_TYPE "application/problem+json"

/* New reference with an empty "errors" list; NULL only when out of memory. */
json_t *problem_new(int http_status, const char *code, const char *detail);

/* Appends {"pointer": pointer, "detail": detail} to the problem's errors. */
void problem_add_error(json_t *problem, const char *pointer, const char *detail);

/* Standard reason phrase for the statuses the service answers with. */
const char *problem_title(int http_status);

#endif
