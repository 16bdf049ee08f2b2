/* commands.h — the subcommands of the one `nscatter` binary. Each takes the arguments
 * after its own name (argv[0] is the subcommand name) and returns the process exit status:
 * 0 success, 1 failure while working, 2 bad usage or bad input. */
#ifndef NS_COMMANDS_H
#define NS_COMMANDS_H

int cmd_info(int argc, char **argv);   /* server/cmd_info.c: chosen device and driver */
int cmd_render(int argc, char **argv); /* server/cmd_render.c: scene JSON -> PNG/EXR */
int cmd_serve(int argc, char **argv);  /* server/http.c: the HTTP service */
int cmd_mc(int argc, char **argv);     /* offline/mc_cli.c: Monte Carlo tables */
int cmd_train(int argc, char **argv);  /* offline/train.c: fit the scattering networks */
int cmd_table(int argc, char **argv);  /* server/cmd_table.c: NN/MC table, accuracy report */
int cmd_compare(int argc, char **argv); /* server/cmd_compare.c: PSNR/RMSE of two images */
int cmd_bench(int argc, char **argv);   /* server/cmd_bench.c: benchmark, report.md */

#endif
