"""Agents: PPO, A2C, ACKTR, DQN in flax + optax (not yet implemented)."""
