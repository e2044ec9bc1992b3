"""Learning: PS-DDPG, the training environments, training, imitation, policies on disk."""
