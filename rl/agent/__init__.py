"""The learned agent: Q-network, replay, double DQN and its training loop."""
