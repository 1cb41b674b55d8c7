"""Results beyond one run: the leaderboard, the HTML report and the CI regression gate's statistics and outputs."""
