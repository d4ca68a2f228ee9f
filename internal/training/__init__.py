"""Training: the jitted train step, its optimizer and its schedules (learning rate, padding, annealing, weights)."""
