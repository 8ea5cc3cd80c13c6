"""The review loop: which frames a person should look at first (frame confidence) and the folder
of frames handed to their labelling tool."""
