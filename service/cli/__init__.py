"""`python -m service export` (a deformed mesh file) and `python -m service estimate|plan` (the routes' replies),
offline: service/__main__.py hands them their arguments; the app never imports them."""
