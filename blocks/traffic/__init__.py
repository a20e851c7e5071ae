"""The traffic scheduler: who may occupy which node when, each vehicle's control loop,
and the resolution of waits-for cycles between vehicles."""
