/* Placeholder until this command lands; replaced by its real implementation. */
#include <stdio.h>
#include "../server/commands.h"

int cmd_mc(int argc, char **argv)
{
    fprintf(stderr, "nscatter %s: not implemented yet\n", argv[0]);
    return 1;
}
