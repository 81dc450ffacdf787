"""Simulated calibration cell (SPEC section 5): true robot, designs, measurements."""

# The most configurations a simulated design has: a campaign measures tens to a few thousand;
# the space-filling thinning grows as N^2, a camera cell's design as 3 N inverse kinematics.
MAX_CONFIGURATIONS = 20000
