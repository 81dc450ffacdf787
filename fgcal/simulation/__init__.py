"""Simulated calibration cell (SPEC section 5): true robot, designs, measurements."""
