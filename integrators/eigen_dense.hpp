// Eigen's dense solvers (SelfAdjointEigenSolver, LU, geometry) without GCC 12's false
// -Wmaybe-uninitialized inside Eigen 3.4's triangular/selfadjoint matrix-vector kernels.
// A diagnostic pragma applies to the source lines it encloses, so this header must be the
// first thing a translation unit includes that pulls in Eigen.
#pragma once

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <Eigen/Dense>
#include <Eigen/Geometry>
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
