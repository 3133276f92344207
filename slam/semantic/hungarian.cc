#include "slam/semantic/hungarian.h"

#include <glog/logging.h>

#include <algorithm>
#include <limits>

namespace twist::semantic {

std::vector<int> SolveAssignment(const Eigen::MatrixXd& cost) {
  const int rows = static_cast<int>(cost.rows());
  const int cols = static_cast<int>(cost.cols());
  std::vector<int> out(static_cast<size_t>(rows), -1);
  if (rows == 0 || cols == 0) return out;
  CHECK(cost.allFinite()) << "assignment costs must be finite";
  // Work on n <= m (transpose if needed).
  const bool transposed = rows > cols;
  const Eigen::MatrixXd a = transposed ? Eigen::MatrixXd(cost.transpose()) : cost;
  const int n = static_cast<int>(a.rows());
  const int m = static_cast<int>(a.cols());
  const double inf = std::numeric_limits<double>::infinity();
  // 1-based potentials u (rows), v (cols); p[j] = row matched to column j.
  std::vector<double> u(static_cast<size_t>(n + 1), 0.0), v(static_cast<size_t>(m + 1), 0.0);
  std::vector<int> p(static_cast<size_t>(m + 1), 0), way(static_cast<size_t>(m + 1), 0);
  for (int i = 1; i <= n; ++i) {
    p[0] = i;
    int j0 = 0;
    std::vector<double> minv(static_cast<size_t>(m + 1), inf);
    std::vector<char> used(static_cast<size_t>(m + 1), 0);
    do {
      used[static_cast<size_t>(j0)] = 1;
      const int i0 = p[static_cast<size_t>(j0)];
      double delta = inf;
      int j1 = 0;
      for (int j = 1; j <= m; ++j) {
        if (used[static_cast<size_t>(j)]) continue;
        const double cur =
            a(i0 - 1, j - 1) - u[static_cast<size_t>(i0)] - v[static_cast<size_t>(j)];
        if (cur < minv[static_cast<size_t>(j)]) {
          minv[static_cast<size_t>(j)] = cur;
          way[static_cast<size_t>(j)] = j0;
        }
        if (minv[static_cast<size_t>(j)] < delta) {
          delta = minv[static_cast<size_t>(j)];
          j1 = j;
        }
      }
      for (int j = 0; j <= m; ++j) {
        if (used[static_cast<size_t>(j)]) {
          u[static_cast<size_t>(p[static_cast<size_t>(j)])] += delta;
          v[static_cast<size_t>(j)] -= delta;
        } else {
          minv[static_cast<size_t>(j)] -= delta;
        }
      }
      j0 = j1;
    } while (p[static_cast<size_t>(j0)] != 0);
    do {
      const int j1 = way[static_cast<size_t>(j0)];
      p[static_cast<size_t>(j0)] = p[static_cast<size_t>(j1)];
      j0 = j1;
    } while (j0 != 0);
  }
  for (int j = 1; j <= m; ++j) {
    const int i = p[static_cast<size_t>(j)];
    if (i == 0) continue;
    if (transposed) {
      out[static_cast<size_t>(j - 1)] = i - 1;
    } else {
      out[static_cast<size_t>(i - 1)] = j - 1;
    }
  }
  return out;
}

std::vector<int> MaxScoreAssignment(const Eigen::MatrixXd& score, double min_score) {
  // Pairs below the gate get cost 0 (as good as staying unassigned), so they
  // never displace a valid pair; they are dropped afterwards.
  Eigen::MatrixXd cost(score.rows(), score.cols());
  for (int i = 0; i < score.rows(); ++i) {
    for (int j = 0; j < score.cols(); ++j) {
      cost(i, j) = score(i, j) >= min_score ? -score(i, j) : 0.0;
    }
  }
  std::vector<int> out = SolveAssignment(cost);
  for (size_t i = 0; i < out.size(); ++i) {
    if (out[i] >= 0 && score(static_cast<int>(i), out[i]) < min_score) out[i] = -1;
  }
  return out;
}

}  // namespace twist::semantic
