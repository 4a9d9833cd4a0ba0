import torch as th

# Tiny networks run fastest on one thread, and pytest-xdist already runs one worker per core
th.set_num_threads(1)
