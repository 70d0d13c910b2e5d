"""The ports layer: what bridges fill and the loop reads (no maths, no transport)."""
