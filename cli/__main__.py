"""``python -m uavplace.cli uavdata|uavrl COMMAND ...``."""

from uavplace.cli import main

main()
