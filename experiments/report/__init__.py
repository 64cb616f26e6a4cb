"""What a command prints when it is done, read back from the files it wrote: the terminal
summaries that the commands and the studies share."""
