/* nscatter — one binary, many subcommands. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "commands.h"
#include "huge_pages.h"
#include "nscatter.h"

typedef struct {
    const char *name;
    int (*run)(int argc, char **argv);
    const char *summary;
} subcommand;

static const subcommand subcommands[] = {
    {"serve", cmd_serve, "run the HTTP render service (web page at /)"},
    {"render", cmd_render, "render a scene JSON file to PNG or EXR"},
    {"info", cmd_info, "print the chosen Vulkan device and driver"},
    {"mc", cmd_mc, "Monte Carlo scattering tables (one material, or the training grid)"},
    {"train", cmd_train, "train the double/multiple scattering networks on the Monte Carlo grid"},
    {"table", cmd_table, "reconstruct a table from the networks (GPU), or compare it with MC"},
    {"compare", cmd_compare, "PSNR, RMSE and relative error of an image against a reference"},
    {"bench", cmd_bench, "the paper's experiments on built-in scenes against pt references"},
};

static void usage(FILE *out)
{
    fprintf(out, "nscatter %s — neural scattering renderer\n\nusage: nscatter <command> [options]\n\n",
            NS_VERSION);
    for (size_t i = 0; i < sizeof subcommands / sizeof subcommands[0]; i++)
        fprintf(out, "  %-8s %s\n", subcommands[i].name, subcommands[i].summary);
    fprintf(out, "\n`nscatter <command> --help` describes a command's options.\n");
}

int main(int argc, char **argv)
{
    /* Returns in the process that has them, or cannot have them. */
    if (huge_pages_start(argv)) {
        fprintf(stderr,
                "nscatter: NSCATTER_HUGE_PAGES: '%s' is neither 0 (off) nor 1 (on, the "
                "default)\n",
                getenv("NSCATTER_HUGE_PAGES"));
        return 2;
    }
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h") || !strcmp(argv[1], "help")) {
        usage(stdout);
        return 0;
    }
    if (!strcmp(argv[1], "--version")) {
        printf("nscatter %s\n", NS_VERSION);
        return 0;
    }
    for (size_t i = 0; i < sizeof subcommands / sizeof subcommands[0]; i++)
        if (!strcmp(argv[1], subcommands[i].name))
            return subcommands[i].run(argc - 1, argv + 1);
    fprintf(stderr, "nscatter: unknown command '%s'\n\n", argv[1]);
    usage(stderr);
    return 2;
}
