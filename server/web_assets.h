/* web_assets.h — the web page's files, embedded at build time (cmake/embed_web.cmake). */
#ifndef NS_WEB_ASSETS_H
#define NS_WEB_ASSETS_H

#include <stddef.h>

typedef struct web_asset {
    const char *name;         /* file name in web/, e.g. "app.js" (no directories) */
    const char *content_type; /* e.g. "text/javascript; charset=utf-8" */
    const unsigned char *data;
    size_t size;
} web_asset;

/* Generated table, web_asset_count entries followed by a zeroed sentinel. */
extern const web_asset web_assets[];
extern const size_t web_asset_count;

/* The asset called `name` (exact match), or NULL. */
const web_asset *web_asset_find(const char *name);

#endif
