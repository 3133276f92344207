// Optimal assignment (Hungarian / Kuhn–Munkres with potentials, O(n³)).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace twist::semantic {

// Minimises the total cost of a one-to-one assignment of rows to columns of a
// rectangular cost matrix (every row of the smaller dimension gets a partner).
// Returns, for each row, its column or -1. Costs must be finite.
std::vector<int> SolveAssignment(const Eigen::MatrixXd& cost);

// Maximises the total score; pairs with score < min_score are left unassigned
// (their rows get -1), so weak pairs never block better ones.
std::vector<int> MaxScoreAssignment(const Eigen::MatrixXd& score, double min_score);

}  // namespace twist::semantic
