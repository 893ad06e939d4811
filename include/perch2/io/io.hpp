// All of perch2's file I/O (link perch2::io).
#pragma once

#include "perch2/io/image_io.hpp"
#include "perch2/io/mesh_io.hpp"
