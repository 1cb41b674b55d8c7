"""Simulators behind the EnvAdapter contract (robosuite, Meta-World, ManiSkill, Gymnasium), cameras, perturbation axes."""
