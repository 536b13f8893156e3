within MotionTwin;
package Controllers "Joint controllers. Sampled controllers are written as linear continuous laws with a sample period Ts and the class annotation __motiontwin(sampled(period=Ts, method=\"tustin\")): the FMU pipeline Tustin-discretises them at Ts and holds the output between samples"
end Controllers;
