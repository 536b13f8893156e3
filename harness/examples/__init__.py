"""Example scripts; each writes its figure and prints the command-line figures the README quotes."""
