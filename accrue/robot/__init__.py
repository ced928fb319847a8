"""ACCRUE on a robot through lerobot's `Robot` abstraction (paper Sec. V-C), store-agnostic.

    mapping        robot observations -> accrue's state vector, the 6-D normalised delta -> robot actions
    safety         the safety envelope (workspace box, speed, wrist force/torque) that ends an episode
    bridge         any lerobot Robot behind deadlines: connect, observe, act, reconnect - never a hang
    sim_robot      `accrue_sim`: a lerobot Robot backed by accrue's MuJoCo tasks, with injectable faults
    operator       labels, "reset done", pause, abort, re-label (terminal keys or a scripted operator)
    episode        one operator-labelled episode on the robot; its chunk transitions and rewards
    transport      gRPC with bytes payloads and a version handshake
    learner_service / learner_client   the asynchronous learner process and the actor's side of it

The stages/steps/hw_*.py steps put these together and seal what they produce in the store.
Heavy imports (lerobot, torch, grpc, mujoco) stay inside functions.
"""
