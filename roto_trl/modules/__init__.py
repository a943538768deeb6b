"""Agent networks (encoder, policy and value heads) and the policy's distribution, as TensorDict modules."""
