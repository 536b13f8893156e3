within MotionTwin;
package Examples "Assembled examples (continuous-time closed loops for illustration; the FMU pipeline executes sampled controllers separately)"
end Examples;
