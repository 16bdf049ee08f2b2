/* commands.h — the subcommands of the one `nscatter` binary. Each takes the arguments
 * after its own name (argv[0] is the subcommand name) and returns the process exit status:
 * 0 success, 1 failure while working, 2 bad usage or bad input. */
#ifndef NS_COMMANDS_H
#define NS_COMMANDS_H

/* Each lives in cli/cmd_<name>.c; the work itself is in the layers below. */
int cmd_info(int argc, char **argv);    /* chosen device and driver */
int cmd_render(int argc, char **argv);  /* scene JSON -> PNG/EXR (io/render_job.h) */
int cmd_serve(int argc, char **argv);   /* the HTTP service (server/include/http.h) */
int cmd_mc(int argc, char **argv);      /* Monte Carlo tables (offline/mc.h) */
int cmd_train(int argc, char **argv);   /* fit the scattering networks (offline/train.h) */
int cmd_table(int argc, char **argv);   /* NN/MC table, accuracy report */
int cmd_compare(int argc, char **argv); /* PSNR/RMSE of two images (io/image_metrics.h) */
int cmd_bench(int argc, char **argv);   /* benchmark, report.md (cli/bench.h) */

#endif
