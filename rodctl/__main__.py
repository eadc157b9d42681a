"""`python -m rodctl` is the same as the `rodctl` console script."""

from rodctl.cli import main

if __name__ == "__main__":
    main()
