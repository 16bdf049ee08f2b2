/* web_assets.c — lookup in the embedded web page table. */
#include "web_assets.h"

#include <string.h>

const web_asset *web_asset_find(const char *name)
{
    /* Exact names only: the table holds plain file names, so "../x" or "a/b" never match. */
    for (size_t i = 0; name && i < web_asset_count; i++)
        if (!strcmp(web_assets[i].name, name))
            return &web_assets[i];
    return NULL;
}
