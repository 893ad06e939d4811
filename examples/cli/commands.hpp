// The perch2 command-line tool's commands, one file each under examples/cli/. Each returns the process exit
// code.
#pragma once

/// perch2 eval --dataset DIR --results FILE.csv [--split test] [--targets FILE] [--models DIR] [--json OUT]
///             [--no-vsd]. Takes the arguments after the command name (argv[0] is the command).
int run_eval(int argc, char** argv);

/// perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] --seed S --out DIR.
/// Takes the whole command line (argv[1] is "generate").
int run_generate(int argc, char** argv);

/// perch2 estimate --mode 3dof|6dof --dataset DIR --out FILE.csv [...] (see --help). Takes the arguments
/// after the command name.
int run_estimate(int argc, char** argv);

/// perch2 demo [--out DIR] [--backend cpu|thrust_omp] [--seed S]. Takes the arguments after the command name.
int run_demo(int argc, char** argv);

/// perch2 track --dataset DIR --out FILE.csv [--scenes A-B] [--init search|gt] (see --help). Takes the
/// arguments after the command name.
int run_track(int argc, char** argv);
