/* fuzz_options.h — the parse options the scene and sweep fuzzers share: the repository's
 * asset folder (so that asset names meet the real name check and file reads) and service
 * limits low enough that small inputs reach the limit paths. */
#ifndef NS_FUZZ_OPTIONS_H
#define NS_FUZZ_OPTIONS_H

#include "scene_json.h"

static const scene_parse_options fuzz_parse_options = {.asset_dir = NS_SOURCE_DIR "/scenes/assets",
                                                       .max_pixels = 1u << 20,
                                                       .max_spp = 4096,
                                                       .max_vrls = 1u << 16,
                                                       .max_triangles = 1u << 16};

#endif
