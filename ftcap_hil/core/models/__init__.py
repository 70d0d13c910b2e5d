"""Plants: the models the estimator and the offline loop integrate, and controllers."""
