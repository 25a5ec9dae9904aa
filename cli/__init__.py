"""The `contact-skills` command line."""
