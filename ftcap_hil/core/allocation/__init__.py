"""The allocation: the bounded QP, its solver registry, the excitation."""
