/* Placeholder until this command lands; replaced by its real implementation. */
#include <stdio.h>
#include "commands.h"

int cmd_serve(int argc, char **argv)
{
    fprintf(stderr, "nscatter %s: not implemented yet\n", argv[0]);
    return 1;
}
