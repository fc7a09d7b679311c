"""The distributed trainer: a runner process with the learner, and spawned acting processes that
share the replay, the weights and the control state through shared memory (docs/design.md)."""
