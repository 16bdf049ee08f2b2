/* openapi.h — the OpenAPI 3.1 description of the HTTP API (server/openapi.json, served as
 * GET /openapi.json), embedded at build time by cmake/embed_openapi.cmake, which also
 * checks that its info.version is NS_VERSION. */
#ifndef NS_OPENAPI_H
#define NS_OPENAPI_H

#include <stddef.h>

/* application/json rather than the registered application/vnd.oai.openapi+json: browsers
 * show it and tools read it without being told what it is (docs/http.md). */
#define OPENAPI_CONTENT_TYPE "application/json"

/* The document's bytes, openapi_json_size of them, followed by a 0 not counted. */
extern const unsigned char openapi_json[];
extern const size_t openapi_json_size;

#endif
