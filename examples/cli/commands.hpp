// The perch2 command-line tool's commands, one file each under examples/cli/. Each takes the arguments after
// the command name (argv[0] is the command) and returns the process exit code.
#pragma once

/// perch2 eval --dataset DIR --results FILE.csv [--split test] [--targets FILE] [--models DIR] [--json OUT]
///             [--no-vsd]
int run_eval(int argc, char** argv);
