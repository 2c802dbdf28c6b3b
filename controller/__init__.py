"""The fishfarm controller process and its command line."""
