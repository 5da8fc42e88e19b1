"""Reporting: what is made from results files for people to read: leaderboards, ``compare``, figures."""
