"""What fgcal writes for people and other tools from a finished calibration: report.md and
report.json with plots, calibrated_robot.yaml, estimates.yaml. Above the calibration layer:
nothing in fgcal.calibration imports from here."""
