"""Run ``hddpg-cli`` from a checkout: ``python cli.py --help``."""

from sb3_hddpg.cli import main

if __name__ == "__main__":
    main()
