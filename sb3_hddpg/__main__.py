"""``python -m sb3_hddpg``: the same command line as ``hddpg-cli``, from any environment with the package."""

from sb3_hddpg.cli import main

if __name__ == "__main__":
    main()
