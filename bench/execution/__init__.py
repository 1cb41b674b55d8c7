"""Running jobs: one episode (rollout), executors (local processes, Ray), the run's keys and checks, recording."""
