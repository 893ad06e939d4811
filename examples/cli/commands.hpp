// Subcommands of the perch2 command-line tool, one file each (examples/cli/<command>.cpp).
#pragma once

/// perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] --seed S --out DIR
int run_generate(int argc, char** argv);
